//! `atlas.png` + `atlas.json`: impostors of a tile's cloud clusters, pre-shaded for a
//! sun bucket and packed into one texture (Harris & Lastra 2001's impostors, made on
//! the server).
//!
//! **Clusters**: the tile's billboards projected onto a horizontal grid with one cell
//! per metaball spacing; 8-connected groups of occupied cells are clusters, and a
//! cluster wider than [`MAX_CLUSTER_SPACINGS`] spacings is cut along a grid of that
//! size, so a continuous deck becomes several impostors.
//!
//! **Impostors**: each cluster drawn by the billboard compositor with an orthographic
//! camera looking horizontally north (+y), so an impostor's width is world x (east to
//! the right) and its height is altitude (up). A client draws it as a vertical,
//! camera-facing (cylindrical) billboard centred at `centre` with world `size`.
//!
//! **Texel**: one pixel at the nearest distance the tile's level is drawn at
//! (`column / lod_pixels` of the preset), so impostors are as sharp as the screen;
//! an impostor wider than [`MAX_IMPOSTOR_PIXELS`] and an atlas taller than
//! [`MAX_ATLAS_HEIGHT`] get coarser texels.
//!
//! **Keyframes**: an atlas shows its tile at the start `t0` of its keyframe span. At
//! `t` in the span, with `f = (t − t0) / (t1 − t0)`, a client draws this atlas's
//! impostors with opacity × (1 − f), moved by `velocity · (t − t0)`, and the next
//! keyframe's with opacity × f, moved by `−velocity · (t1 − t)`: a cross-fade that
//! glides with the wind.
//!
//! **PNG**: RGBA 8-bit, straight (not premultiplied) alpha; colour is tone-mapped
//! display RGB (`1 − e^{−x}`, gamma 1/2.2). **Manifest** (JSON): the billboard header
//! (tile, sun bucket, lighting) plus `"width"`, `"height"`, `"alpha": "straight"`, and
//! `"impostors": [{"rect": [x, y, w, h] (pixels, y down), "centre": [x, y, z] (world
//! metres), "size": [width, height] (metres), "velocity": [vx, vy] (m/s, the wind at
//! the centre's altitude), "billboards": n}]`.

use std::collections::BTreeMap;

use serde_json::json;

use super::json_f32;
use crate::render::ShadedTile;
use crate::render::camera::View;
use crate::render::composite::composite;
use crate::render::image::Image;
use crate::render::shade::Billboard;

/// Largest cluster side, in metaball spacings, before it is cut.
pub const MAX_CLUSTER_SPACINGS: i64 = 16;
/// Largest impostor side, pixels.
pub const MAX_IMPOSTOR_PIXELS: usize = 256;
/// Atlas width, pixels (the height grows with the content, up to [`MAX_ATLAS_HEIGHT`]).
pub const ATLAS_WIDTH: usize = 2048;
/// Tallest atlas, pixels; impostors that do not fit are left out.
pub const MAX_ATLAS_HEIGHT: usize = 4096;

/// An encoded atlas.
#[derive(Clone, Debug, PartialEq)]
pub struct Atlas {
    /// `atlas.png`: the impostors, RGBA.
    pub png: Vec<u8>,
    /// `atlas.json`: where each impostor is in the PNG and in the world.
    pub manifest: Vec<u8>,
    /// Number of impostors.
    pub impostors: usize,
}

struct Impostor {
    members: Vec<usize>,
    lo: [f64; 3],
    hi: [f64; 3],
}

/// Groups billboards into clusters (see the module docs), in a deterministic order.
fn clusters(tile: &ShadedTile) -> Vec<Vec<usize>> {
    let s = tile.lattice.spacing;
    let mut cells: BTreeMap<(i64, i64), Vec<usize>> = BTreeMap::new();
    for (i, b) in tile.billboards.iter().enumerate() {
        let key = (
            ((b.centre[0] - tile.origin[0]) / s).floor() as i64,
            ((b.centre[1] - tile.origin[1]) / s).floor() as i64,
        );
        cells.entry(key).or_default().push(i);
    }
    let mut label: BTreeMap<(i64, i64), usize> = BTreeMap::new();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for &start in cells.keys() {
        if label.contains_key(&start) {
            continue;
        }
        let id = groups.len();
        let chunk = (
            start.0.div_euclid(MAX_CLUSTER_SPACINGS),
            start.1.div_euclid(MAX_CLUSTER_SPACINGS),
        );
        let mut members = Vec::new();
        let mut stack = vec![start];
        label.insert(start, id);
        while let Some(c) = stack.pop() {
            members.extend_from_slice(&cells[&c]);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let n = (c.0 + dx, c.1 + dy);
                    let same_chunk = (
                        n.0.div_euclid(MAX_CLUSTER_SPACINGS),
                        n.1.div_euclid(MAX_CLUSTER_SPACINGS),
                    ) == chunk;
                    if same_chunk && cells.contains_key(&n) && !label.contains_key(&n) {
                        label.insert(n, id);
                        stack.push(n);
                    }
                }
            }
        }
        members.sort_unstable();
        groups.push(members);
    }
    groups
}

/// Builds the atlas of a shaded tile.
pub fn build(tile: &ShadedTile) -> Atlas {
    let mut impostors: Vec<Impostor> = clusters(tile)
        .into_iter()
        .map(|members| {
            let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            for &i in &members {
                let b = &tile.billboards[i];
                for a in 0..3 {
                    lo[a] = lo[a].min(b.centre[a] - b.radius as f64);
                    hi[a] = hi[a].max(b.centre[a] + b.radius as f64);
                }
            }
            Impostor { members, lo, hi }
        })
        .collect();
    // Tallest first for shelf packing; ties keep cluster order.
    // The texel from the expected pixel footprint (Szécsi): the level choice shows a
    // tile's level while one of its columns spans at most `lod_pixels` pixels, so at
    // its nearest a column covers `lod_pixels` pixels and a texel of
    // `column / lod_pixels` is one pixel there (no magnification blur).
    let base_mpp = tile.column / tile.quality.settings().lod_pixels.max(1.0);
    let mut scale = 1.0;
    loop {
        let mpp = base_mpp * scale;
        let dims: Vec<(usize, usize, f64)> = impostors
            .iter()
            .map(|im| {
                let (w, h) = (im.hi[0] - im.lo[0], im.hi[2] - im.lo[2]);
                let m = mpp.max(w.max(h) / MAX_IMPOSTOR_PIXELS as f64);
                (
                    ((w / m).ceil() as usize).clamp(1, MAX_IMPOSTOR_PIXELS),
                    ((h / m).ceil() as usize).clamp(1, MAX_IMPOSTOR_PIXELS),
                    m,
                )
            })
            .collect();
        let mut order: Vec<usize> = (0..impostors.len()).collect();
        order.sort_by(|&a, &b| dims[b].1.cmp(&dims[a].1).then(a.cmp(&b)));
        let (mut x, mut y, mut shelf) = (0usize, 0usize, 0usize);
        let mut rects = vec![(0usize, 0usize); impostors.len()];
        for &i in &order {
            let (w, h, _) = dims[i];
            if x + w > ATLAS_WIDTH {
                x = 0;
                y += shelf;
                shelf = 0;
            }
            rects[i] = (x, y);
            x += w;
            shelf = shelf.max(h);
        }
        let height = (y + shelf).max(1);
        if height > MAX_ATLAS_HEIGHT {
            scale *= 1.5;
            continue;
        }
        let width = if impostors.is_empty() {
            1
        } else {
            ATLAS_WIDTH.min(order.iter().map(|&i| rects[i].0 + dims[i].0).max().unwrap_or(1))
        };
        let mut atlas = Image::new(width, height);
        let mut entries = Vec::new();
        for (i, im) in impostors.iter_mut().enumerate() {
            let (w, h, m) = dims[i];
            let centre = [
                0.5 * (im.lo[0] + im.hi[0]),
                0.5 * (im.lo[1] + im.hi[1]),
                0.5 * (im.lo[2] + im.hi[2]),
            ];
            let view = View::orthographic(centre, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], m, w, h);
            let mut img = Image::new(w, h);
            let members: Vec<Billboard> = im.members.iter().map(|&k| tile.billboards[k]).collect();
            composite(&mut img, &members, &tile.lighting, &view);
            let (ox, oy) = rects[i];
            for row in 0..h {
                let src = row * w;
                let dst = (oy + row) * width + ox;
                atlas.rgb[dst..dst + w].copy_from_slice(&img.rgb[src..src + w]);
                atlas.alpha[dst..dst + w].copy_from_slice(&img.alpha[src..src + w]);
            }
            entries.push(json!({
                "rect": [ox, oy, w, h],
                "centre": centre.map(json_f32),
                "size": [json_f32(w as f64 * m), json_f32(h as f64 * m)],
                "velocity": tile.velocity_at(centre[2]).map(json_f32),
                "billboards": im.members.len(),
            }));
        }
        let mut manifest = super::billboards::header_json(tile);
        manifest["format"] = json!("cloudscape-atlas");
        manifest["width"] = json!(width);
        manifest["height"] = json!(height);
        manifest["alpha"] = json!("straight");
        manifest["view"] = json!("orthographic, horizontal, looking north (+y); rect x = east, rect y = down");
        manifest["impostors"] = serde_json::Value::Array(entries);
        return Atlas {
            png: atlas.to_png_straight_alpha(),
            manifest: serde_json::to_vec(&manifest).expect("a JSON value serialises"),
            impostors: impostors.len(),
        };
    }
}
