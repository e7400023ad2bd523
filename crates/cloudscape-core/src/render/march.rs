//! The reference renderer: a volumetric ray marcher over the density grids.
//!
//! Single scattering with Beer–Lambert attenuation: along a view ray, each step of
//! length Δ at density ρ has extinction σ = `extinction · ρ` and contributes
//! `T · (1 − e^{−σΔ}) · J`, where `J = albedo · (sun · T_sun · p(cos θ) + ambient)` and
//! `T_sun` comes from a shadow ray marched toward the sun through every volume.
//! Each step's source is seen through the air between it and the eye (aerial
//! perspective, [`Lighting::hazed`]: `J · T_air + L_in`); the sky behind the clouds
//! already holds the air's light, and the ground gets its own haze.
//! Density is trilinear between cell centres (cells beyond a grid are empty).
//! Empty-space skipping: an occupancy grid of 4×4×4-cell bricks holding the largest
//! density any trilinear sample inside the brick can see; rays jump over empty bricks.
//! Early exit when the view transmittance drops below `min_transmittance` or the
//! shadow optical depth exceeds `max_shadow_tau`.

use std::ops::ControlFlow;

use rayon::prelude::*;

use crate::cancel::Cancel;
use crate::density::Grid;
use crate::density::metaballs::GridPlacement;

use super::camera::View;
use super::image::Image;
use super::light::{Lighting, dot};

const BRICK: usize = 4;

/// Step sizes and cut-offs of the ray marcher.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MarchParams {
    /// View-ray step, metres.
    pub step: f64,
    /// Shadow-ray step, metres.
    pub shadow_step: f64,
    /// Stop a view ray when its transmittance falls below this.
    pub min_transmittance: f64,
    /// Stop a shadow ray when its optical depth exceeds this.
    pub max_shadow_tau: f64,
}

impl MarchParams {
    /// Steps of `step` metres along view rays and twice that along shadow rays.
    pub fn with_step(step: f64) -> MarchParams {
        MarchParams {
            step,
            shadow_step: 2.0 * step,
            min_transmittance: 1e-3,
            max_shadow_tau: 12.0,
        }
    }
}

/// One density grid placed in the world, answering for the box `bounds`
/// ([x0, y0, z0, x1, y1, z1], world metres). The grid may extend beyond the box
/// (a halo), so interpolation is seamless across neighbouring volumes.
#[derive(Clone, Debug)]
pub struct Volume {
    /// The density, cells of the layer's level.
    pub grid: Grid<f32>,
    /// Where the grid's cells lie in the world.
    pub place: GridPlacement,
    /// The box this volume answers for: [x0, y0, z0, x1, y1, z1], world metres.
    pub bounds: [f64; 6],
    bricks: Vec<f32>,
    brick_dims: [usize; 3],
    /// The largest brick value: a majorant of the whole volume.
    max_density: f32,
}

impl Volume {
    /// A volume of `grid` placed by `place`, answering for `bounds` (world metres).
    pub fn new(grid: Grid<f32>, place: GridPlacement, bounds: [f64; 6]) -> Volume {
        let dims = [
            grid.cols.div_ceil(BRICK),
            grid.rows.div_ceil(BRICK),
            grid.depth.div_ceil(BRICK),
        ];
        let mut bricks = vec![0.0f32; dims[0] * dims[1] * dims[2]];
        // A trilinear sample in brick b reads cells up to one beyond it: spread each
        // cell's value to every brick whose (1-cell expanded) box holds it.
        for k in 0..grid.depth {
            for r in 0..grid.rows {
                for c in 0..grid.cols {
                    let v = grid.get(k, r, c);
                    if v <= 0.0 {
                        continue;
                    }
                    let span = |i: usize, n: usize| {
                        let lo = i.saturating_sub(1) / BRICK;
                        let hi = ((i + 1) / BRICK).min(n - 1);
                        lo..=hi
                    };
                    for bk in span(k, dims[2]) {
                        for br in span(r, dims[1]) {
                            for bc in span(c, dims[0]) {
                                let i = (bk * dims[1] + br) * dims[0] + bc;
                                bricks[i] = bricks[i].max(v);
                            }
                        }
                    }
                }
            }
        }
        let max_density = bricks.iter().copied().fold(0.0f32, f32::max);
        Volume {
            grid,
            place,
            bounds,
            bricks,
            brick_dims: dims,
            max_density,
        }
    }

    /// The largest density a trilinear sample anywhere in the volume can see.
    pub fn max_density(&self) -> f64 {
        self.max_density as f64
    }

    /// The shortest side of a brick, metres.
    pub fn brick_size(&self) -> f64 {
        BRICK as f64 * self.place.column.min(self.place.cell_height)
    }

    /// Continuous cell coordinates of a world point (cell centres at integers).
    #[inline]
    fn cell_coords(&self, p: [f64; 3]) -> [f64; 3] {
        [
            (p[0] - self.place.x0) / self.place.column - 0.5,
            (p[1] - self.place.y0) / self.place.column - 0.5,
            (p[2] - self.place.base) / self.place.cell_height - 0.5,
        ]
    }

    /// Trilinear density at `p` (0 beyond the grid).
    pub fn density(&self, p: [f64; 3]) -> f64 {
        let q = self.cell_coords(p);
        let g = &self.grid;
        let (fx, fy, fz) = (q[0].floor(), q[1].floor(), q[2].floor());
        let (tx, ty, tz) = (q[0] - fx, q[1] - fy, q[2] - fz);
        let (x0, y0, z0) = (fx as i64, fy as i64, fz as i64);
        let at = |x: i64, y: i64, z: i64| -> f64 {
            if x < 0 || y < 0 || z < 0 || x as usize >= g.cols || y as usize >= g.rows || z as usize >= g.depth {
                0.0
            } else {
                g.data[(z as usize * g.rows + y as usize) * g.cols + x as usize] as f64
            }
        };
        let mut s = 0.0;
        for (dz, wz) in [(0, 1.0 - tz), (1, tz)] {
            for (dy, wy) in [(0, 1.0 - ty), (1, ty)] {
                for (dx, wx) in [(0, 1.0 - tx), (1, tx)] {
                    let w = wx * wy * wz;
                    if w > 0.0 {
                        s += w * at(x0 + dx, y0 + dy, z0 + dz);
                    }
                }
            }
        }
        s
    }

    /// If `p` lies in an empty brick, the ray parameter where (`o`, `d`) leaves it.
    fn skip(&self, o: [f64; 3], d: [f64; 3], t: f64) -> Option<f64> {
        let p = [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
        let q = self.cell_coords(p).map(|v| v + 0.5);
        let b = [0, 1, 2].map(|i| (q[i] / BRICK as f64).floor());
        if (0..3).any(|i| b[i] < 0.0 || b[i] >= self.brick_dims[i] as f64) {
            return None;
        }
        let idx = (b[2] as usize * self.brick_dims[1] + b[1] as usize) * self.brick_dims[0] + b[0] as usize;
        if self.bricks[idx] > 0.0 {
            return None;
        }
        let sizes = [self.place.column, self.place.column, self.place.cell_height];
        let origins = [self.place.x0, self.place.y0, self.place.base];
        let mut exit = f64::INFINITY;
        for i in 0..3 {
            if d[i].abs() < 1e-12 {
                continue;
            }
            let lo = origins[i] + b[i] * BRICK as f64 * sizes[i];
            let hi = lo + BRICK as f64 * sizes[i];
            let plane = if d[i] > 0.0 { hi } else { lo };
            exit = exit.min((plane - o[i]) / d[i]);
        }
        if exit.is_finite() {
            Some(exit.max(t) + 1e-6 * sizes[0])
        } else {
            None
        }
    }

    /// Visits, in order, the bricks that the ray (`o`, `d`) crosses within
    /// [`t0`, `t1`], as `visit(t_enter, t_exit, max_density)` with the largest density
    /// a trilinear sample inside the brick can see (the majorant of delta and ratio
    /// tracking), until `visit` returns false. Beyond the bricks the density is 0.
    /// Grid traversal of Amanatides & Woo 1987 ("A fast voxel traversal algorithm").
    pub fn visit_bricks(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        t0: f64,
        t1: f64,
        mut visit: impl FnMut(f64, f64, f64) -> bool,
    ) {
        let size = [
            BRICK as f64 * self.place.column,
            BRICK as f64 * self.place.column,
            BRICK as f64 * self.place.cell_height,
        ];
        let origin = [self.place.x0, self.place.y0, self.place.base];
        let dims = self.brick_dims;
        // Clip to the bricks' box.
        let (mut ta, mut tb) = (t0, t1);
        for i in 0..3 {
            let (lo, hi) = (origin[i], origin[i] + dims[i] as f64 * size[i]);
            if d[i] == 0.0 {
                if o[i] < lo || o[i] >= hi {
                    return;
                }
                continue;
            }
            let (a, b) = ((lo - o[i]) / d[i], (hi - o[i]) / d[i]);
            ta = ta.max(a.min(b));
            tb = tb.min(a.max(b));
        }
        if !(ta < tb) {
            return;
        }
        let mut cell = [0usize; 3];
        let mut next = [f64::INFINITY; 3];
        let mut delta = [f64::INFINITY; 3];
        for i in 0..3 {
            // The brick holding the entry point. Rounding on a brick face may pick the
            // neighbour behind it: that brick is then visited for a zero length.
            let c = ((o[i] + d[i] * ta - origin[i]) / size[i]).floor();
            cell[i] = if c < 0.0 { 0 } else { (c as usize).min(dims[i] - 1) };
            if d[i] > 0.0 {
                next[i] = (origin[i] + (cell[i] + 1) as f64 * size[i] - o[i]) / d[i];
                delta[i] = size[i] / d[i];
            } else if d[i] < 0.0 {
                next[i] = (origin[i] + cell[i] as f64 * size[i] - o[i]) / d[i];
                delta[i] = -size[i] / d[i];
            }
        }
        let mut t = ta;
        loop {
            let axis = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            let exit = next[axis].min(tb).max(t);
            let idx = (cell[2] * dims[1] + cell[1]) * dims[0] + cell[0];
            if !visit(t, exit, self.bricks[idx] as f64) || exit >= tb {
                return;
            }
            let step_out = if d[axis] > 0.0 {
                cell[axis] + 1 >= dims[axis]
            } else {
                cell[axis] == 0
            };
            if step_out {
                return;
            }
            if d[axis] > 0.0 {
                cell[axis] += 1;
            } else {
                cell[axis] -= 1;
            }
            next[axis] += delta[axis];
            t = exit;
        }
    }

    /// Entry and exit of the ray in the volume's box, clipped to [t_min, t_max].
    fn interval(&self, o: [f64; 3], d: [f64; 3], t_min: f64, t_max: f64) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (t_min, t_max);
        for i in 0..3 {
            let (lo, hi) = (self.bounds[i], self.bounds[i + 3]);
            if d[i].abs() < 1e-15 {
                if o[i] < lo || o[i] > hi {
                    return None;
                }
                continue;
            }
            let (a, b) = ((lo - o[i]) / d[i], (hi - o[i]) / d[i]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        if t0 < t1 { Some((t0, t1)) } else { None }
    }
}

/// The volumes a ray crosses within [t_min, t_max], sorted by entry.
pub(super) fn intervals(
    volumes: &[Volume],
    o: [f64; 3],
    d: [f64; 3],
    t_min: f64,
    t_max: f64,
) -> Vec<(usize, f64, f64)> {
    let mut v: Vec<(usize, f64, f64)> = volumes
        .iter()
        .enumerate()
        .filter_map(|(i, vol)| vol.interval(o, d, t_min, t_max).map(|(a, b)| (i, a, b)))
        .collect();
    v.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    v
}

/// Optical depth from `p` toward the sun through all volumes (capped at `max_shadow_tau`).
pub fn shadow_tau(volumes: &[Volume], p: [f64; 3], sun: [f64; 3], extinction: f64, params: &MarchParams) -> f64 {
    optical_depth(
        volumes,
        p,
        sun,
        f64::INFINITY,
        extinction,
        params.shadow_step,
        params.max_shadow_tau,
    )
}

/// Optical depth along the ray (`o`, `d`) over [0, `t_max`] through all volumes,
/// midpoint rule with steps of `step` metres (empty bricks skipped); stops at `cap`.
pub fn optical_depth(
    volumes: &[Volume],
    o: [f64; 3],
    d: [f64; 3],
    t_max: f64,
    extinction: f64,
    step: f64,
    cap: f64,
) -> f64 {
    let mut tau = 0.0;
    let walk = midpoints(volumes, o, d, t_max, step, |vol, p, dt| {
        tau += extinction * vol.density(p) * dt;
        if tau > cap {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    if walk.is_break() { cap } else { tau }
}

/// Walks the ray (`o`, `d`) over [0, `t_max`] through `volumes` in steps of at most
/// `step` metres (empty bricks skipped), calling `sample(volume, point, dt)` at each
/// step's midpoint until it breaks: the midpoint rule of [`optical_depth`] and
/// [`march_ray`].
fn midpoints(
    volumes: &[Volume],
    o: [f64; 3],
    d: [f64; 3],
    t_max: f64,
    step: f64,
    mut sample: impl FnMut(&Volume, [f64; 3], f64) -> ControlFlow<()>,
) -> ControlFlow<()> {
    for (i, t0, t1) in intervals(volumes, o, d, 0.0, t_max) {
        let vol = &volumes[i];
        let mut t = t0;
        while t < t1 {
            if let Some(next) = vol.skip(o, d, t) {
                t = next;
                continue;
            }
            let dt = step.min(t1 - t);
            let m = t + 0.5 * dt;
            sample(vol, [o[0] + d[0] * m, o[1] + d[1] * m, o[2] + d[2] * m], dt)?;
            t += dt;
        }
    }
    ControlFlow::Continue(())
}

/// The optical depth of every pixel's view ray of `view` through `volumes`, up to the
/// ground (altitude 0), row-major; steps of `step` metres, capped at `cap`. Rows are
/// independent, so the result does not depend on the thread count.
pub fn view_optical_depth(volumes: &[Volume], extinction: f64, view: &View, step: f64, cap: f64) -> Vec<f64> {
    (0..view.height)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..view.width).map(move |x| {
                let (o, d) = view.ray(x as f64 + 0.5, y as f64 + 0.5);
                let t_max = if d[2] < 0.0 && o[2] > 0.0 {
                    -o[2] / d[2]
                } else {
                    f64::INFINITY
                };
                optical_depth(volumes, o, d, t_max, extinction, step, cap)
            })
        })
        .collect()
}

/// Radiance and transmittance along one view ray up to `t_max`. With `aerial`,
/// each sample is seen through the air between it and `o` (the eye); without it
/// (orthographic views, whose ray origins are no eye) it is not.
pub fn march_ray(
    volumes: &[Volume],
    lighting: &Lighting,
    params: &MarchParams,
    o: [f64; 3],
    d: [f64; 3],
    t_max: f64,
    aerial: bool,
) -> ([f64; 3], f64) {
    let sigma_max = lighting.params.extinction;
    let sigma_max = if sigma_max.is_finite() { sigma_max.max(0.0) } else { 1e6 };
    let sun = lighting.sun_dir;
    let phase = lighting.params.phase.eval(dot(d, sun));
    let sun_up = lighting.sun_rgb.iter().any(|&c| c > 0.0);
    let mut radiance = [0.0; 3];
    let mut trans = 1.0;
    let walk = midpoints(volumes, o, d, t_max, params.step, |vol, p, dt| {
        let rho = vol.density(p);
        if rho > 0.0 {
            let a = 1.0 - (-sigma_max * rho * dt).exp();
            let t_sun = if sun_up {
                (-shadow_tau(volumes, p, sun, sigma_max, params)).exp()
            } else {
                0.0
            };
            // Seen through the air between the eye and the sample (aerial
            // perspective, as the compositor hazes each billboard by its distance).
            let j = lighting.source_with_phase(t_sun, phase);
            let j = if aerial { lighting.hazed(j, o, p) } else { j };
            for c in 0..3 {
                radiance[c] += trans * a * j[c];
            }
            trans *= 1.0 - a;
            if trans < params.min_transmittance {
                return ControlFlow::Break(());
            }
        }
        ControlFlow::Continue(())
    });
    if walk.is_break() {
        (radiance, 0.0)
    } else {
        (radiance, trans)
    }
}

/// Renders `view` over `volumes`: clouds (hazed by the air in perspective views),
/// then the sky or the ground (at altitude 0,
/// shadowed by a shadow ray) behind them. Rows are independent, so the image does
/// not depend on the thread count.
pub fn render(volumes: &[Volume], lighting: &Lighting, params: &MarchParams, view: &View, background: bool) -> Image {
    render_cancellable(volumes, lighting, params, view, background, &Cancel::never())
}

/// [`render`] that leaves the remaining rows black once `cancel` fires (the caller
/// then discards the image).
pub fn render_cancellable(
    volumes: &[Volume],
    lighting: &Lighting,
    params: &MarchParams,
    view: &View,
    background: bool,
    cancel: &Cancel,
) -> Image {
    let aerial = matches!(view.kind, super::camera::ViewKind::Perspective { .. });
    render_with_air(volumes, lighting, params, view, background, aerial, cancel)
}

/// [`render_cancellable`] with aerial perspective switched by `aerial` (tests compare
/// the cloud alone against renderers without air).
pub(crate) fn render_with_air(
    volumes: &[Volume],
    lighting: &Lighting,
    params: &MarchParams,
    view: &View,
    background: bool,
    aerial: bool,
    cancel: &Cancel,
) -> Image {
    let mut img = Image::new(view.width, view.height);
    let width = view.width;
    let rows: Vec<(Vec<[f32; 3]>, Vec<f32>)> = (0..view.height)
        .into_par_iter()
        .map(|y| {
            let mut rgb = Vec::with_capacity(width);
            let mut alpha = Vec::with_capacity(width);
            if cancel.is_fired() {
                return (vec![[0.0; 3]; width], vec![0.0; width]);
            }
            for x in 0..width {
                let (o, d) = view.ray(x as f64 + 0.5, y as f64 + 0.5);
                let (c, a) = trace(volumes, lighting, params, o, d, background, aerial);
                rgb.push(c);
                alpha.push(a);
            }
            (rgb, alpha)
        })
        .collect();
    for (y, (rgb, alpha)) in rows.into_iter().enumerate() {
        img.rgb[y * width..(y + 1) * width].copy_from_slice(&rgb);
        img.alpha[y * width..(y + 1) * width].copy_from_slice(&alpha);
    }
    img
}

fn trace(
    volumes: &[Volume],
    lighting: &Lighting,
    params: &MarchParams,
    o: [f64; 3],
    d: [f64; 3],
    background: bool,
    aerial: bool,
) -> ([f32; 3], f32) {
    let ground_t = if d[2] < 0.0 && o[2] > 0.0 {
        -o[2] / d[2]
    } else {
        f64::INFINITY
    };
    let (c, trans) = march_ray(volumes, lighting, params, o, d, ground_t, aerial);
    if !background {
        return (c.map(|v| v as f32), (1.0 - trans) as f32);
    }
    let bg = if ground_t.is_finite() {
        let g = [o[0] + d[0] * ground_t, o[1] + d[1] * ground_t, 0.0];
        let t_sun = if lighting.sun_dir[2] > 0.0 {
            (-shadow_tau(volumes, g, lighting.sun_dir, lighting.params.extinction, params)).exp()
        } else {
            1.0
        };
        lighting.background(o, d, t_sun)
    } else {
        lighting.background(o, d, 1.0)
    };
    ([0, 1, 2].map(|i| (c[i] + trans * bg[i]) as f32), 1.0)
}
