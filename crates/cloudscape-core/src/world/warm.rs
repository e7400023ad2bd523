//! Play areas kept warm (`[[worlds.NAME.warm]]`): places players gather (towns,
//! harbours), whose tiles the server keeps computed for the current and the next
//! keyframe whether anyone asks or not, so that the first view of a town is a cache hit.
//!
//! This module holds what the configuration says and the geometry of it (which
//! rectangles of the world an area reaches); which tiles, products and qualities that
//! makes, and the keeping itself, are the server's (`cloudscape-server`'s `warm`).

use serde::Serialize;

use super::authored::Area;

/// The products an area keeps warm when it names none: what the viewer and game clients
/// fetch per tile (one shading gives both).
pub const DEFAULT_WARM_PRODUCTS: [&str; 2] = ["billboards.bin", "billboards.delta.bin"];
/// The quality an area keeps warm when it names none: the viewer's default.
pub const DEFAULT_WARM_QUALITY: &str = "fast";

/// How far around a play area its tiles are kept warm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Margin {
    /// The same distance at every level, metres (`margin = 2000.0`; 0: the tiles the
    /// area itself touches).
    Metres(f64),
    /// `margin = "view"`: at each level of each layer, as far as a viewer standing in
    /// the area draws tiles of that level (the server's rule, from the level choice of
    /// the renderer).
    #[serde(serialize_with = "view")]
    View,
}

fn view<S: serde::Serializer>(s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str("view")
}

/// One play area kept warm.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WarmArea {
    /// Its name, unique in its world.
    pub name: String,
    /// Where it is: a box `[x0, y0, x1, y1]` or a polygon, world metres.
    pub area: Area,
    /// How far around it tiles are kept warm too.
    pub margin: Margin,
    /// Tile levels kept warm, ascending.
    pub levels: Vec<u32>,
    /// Tile product names (`billboards.bin`, …), checked against the catalogue by the
    /// server that keeps them.
    pub products: Vec<String>,
    /// Quality preset names of the shaded products (`fast`, …), checked likewise.
    pub qualities: Vec<String>,
    /// Indices of the world's layers kept warm, in the world's order.
    pub layers: Vec<usize>,
}

impl WarmArea {
    /// The area's bounding box `[x0, y0, x1, y1]`, metres (without the margin).
    pub fn bounds(&self) -> [f64; 4] {
        match &self.area {
            Area::Box(b) => *b,
            Area::Polygon(p) => p.bounds(),
        }
    }

    /// The polygon's vertices, or `None` for a box.
    pub fn polygon(&self) -> Option<&[[f64; 2]]> {
        match &self.area {
            Area::Box(_) => None,
            Area::Polygon(p) => Some(p.vertices()),
        }
    }

    /// Whether the rectangle `[x0, y0, x1, y1]` (metres) comes within `m` metres of the
    /// area: shares a point with it, or lies at most `m` from its edge.
    pub fn reaches(&self, rect: [f64; 4], m: f64) -> bool {
        let [x0, y0, x1, y1] = rect;
        let [a0, b0, a1, b1] = self.bounds();
        // Outside the bounding box grown by the margin, nothing of the area is near.
        if x1 < a0 - m || a1 + m < x0 || y1 < b0 - m || b1 + m < y0 {
            return false;
        }
        match &self.area {
            // Apart along x, along y, or both (then the corners are nearest).
            Area::Box(_) => {
                let dx = (a0 - x1).max(x0 - a1).max(0.0);
                let dy = (b0 - y1).max(y0 - b1).max(0.0);
                dx.hypot(dy) <= m
            }
            Area::Polygon(p) => {
                let v = p.vertices();
                // The rectangle inside the polygon (a corner of it inside), or an edge
                // within the margin of the rectangle (which covers edges crossing it and
                // a polygon inside it).
                let corner_inside = [[x0, y0], [x1, y0], [x0, y1], [x1, y1]]
                    .iter()
                    .any(|&[x, y]| self.area.depth(x, y) >= 0.0);
                corner_inside || (0..v.len()).any(|i| segment_rect_distance(v[i], v[(i + 1) % v.len()], rect) <= m)
            }
        }
    }
}

/// Distance from the segment `a`–`b` to the rectangle `[x0, y0, x1, y1]` (0 when they
/// meet), metres.
fn segment_rect_distance(a: [f64; 2], b: [f64; 2], rect: [f64; 4]) -> f64 {
    let [x0, y0, x1, y1] = rect;
    let inside = |p: [f64; 2]| x0 <= p[0] && p[0] <= x1 && y0 <= p[1] && p[1] <= y1;
    if inside(a) || inside(b) {
        return 0.0;
    }
    let corners = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
    let sides = (0..4).map(|i| (corners[i], corners[(i + 1) % 4]));
    if sides.clone().any(|(c, d)| segments_cross(a, b, c, d)) {
        return 0.0;
    }
    // Apart: the nearest points are an end of one segment against the other.
    let to_rect = |p: [f64; 2]| {
        let dx = (x0 - p[0]).max(0.0).max(p[0] - x1);
        let dy = (y0 - p[1]).max(0.0).max(p[1] - y1);
        dx.hypot(dy)
    };
    let corner_to_segment = corners.iter().map(|&c| point_segment_distance(c, a, b));
    corner_to_segment.fold(to_rect(a).min(to_rect(b)), f64::min)
}

fn point_segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let len2 = ex * ex + ey * ey;
    let f = if len2 > 0.0 {
        (((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - f * ex).hypot(p[1] - a[1] - f * ey)
}

/// Whether the segments `a`–`b` and `c`–`d` share a point.
fn segments_cross(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let orient = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
    let on = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| {
        r[0] >= p[0].min(q[0]) && r[0] <= p[0].max(q[0]) && r[1] >= p[1].min(q[1]) && r[1] <= p[1].max(q[1])
    };
    let (d1, d2, d3, d4) = (orient(c, d, a), orient(c, d, b), orient(a, b, c), orient(a, b, d));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0)) && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0)) {
        return true;
    }
    (d1 == 0.0 && on(c, d, a)) || (d2 == 0.0 && on(c, d, b)) || (d3 == 0.0 && on(a, b, c)) || (d4 == 0.0 && on(a, b, d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::authored::Polygon;

    fn area(area: Area) -> WarmArea {
        WarmArea {
            name: "town".into(),
            area,
            margin: Margin::Metres(0.0),
            levels: vec![0],
            products: vec![],
            qualities: vec![],
            layers: vec![0],
        }
    }

    #[test]
    fn a_box_reaches_the_rectangles_it_overlaps_or_comes_near() {
        let a = area(Area::Box([0.0, 0.0, 1000.0, 1000.0]));
        assert!(a.reaches([500.0, 500.0, 2000.0, 2000.0], 0.0));
        assert!(a.reaches([-10.0, -10.0, 2000.0, 2000.0], 0.0));
        assert!(!a.reaches([1100.0, 0.0, 2000.0, 1000.0], 0.0));
        assert!(a.reaches([1100.0, 0.0, 2000.0, 1000.0], 200.0));
        assert!(!a.reaches([1300.0, 0.0, 2000.0, 1000.0], 200.0));
        // Diagonally apart: 150 m along each axis is 212 m.
        assert!(!a.reaches([1150.0, 1150.0, 2000.0, 2000.0], 200.0));
        assert!(a.reaches([1150.0, 1150.0, 2000.0, 2000.0], 220.0));
    }

    #[test]
    fn a_polygon_reaches_what_it_crosses_holds_or_is_held_by() {
        // A triangle with its right angle at the origin: the far corner of its bounding
        // box is outside it.
        let triangle = || Area::Polygon(Polygon::new(vec![[0.0, 0.0], [10_000.0, 0.0], [0.0, 10_000.0]]));
        let a = area(triangle());
        // Holds the rectangle.
        assert!(a.reaches([1000.0, 1000.0, 2000.0, 2000.0], 0.0));
        // Is held by it.
        assert!(a.reaches([-1.0, -1.0, 20_000.0, 20_000.0], 0.0));
        // An edge crosses it (no vertex inside, no corner inside).
        assert!(a.reaches([4000.0, -100.0, 4500.0, 100.0], 0.0));
        // In the bounding box, beyond the hypotenuse: (8000, 8000) is 6000/√2 ≈ 4243 m
        // from it.
        let beyond = [8000.0, 8000.0, 9000.0, 9000.0];
        assert!(!a.reaches(beyond, 0.0));
        assert!(a.reaches(beyond, 4300.0));
        assert!(!a.reaches(beyond, 4200.0));
        // Far outside the bounding box.
        assert!(!a.reaches([20_000.0, 0.0, 30_000.0, 100.0], 1000.0));
    }
}
