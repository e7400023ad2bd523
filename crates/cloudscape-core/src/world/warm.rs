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
pub const DEFAULT_WARM_PRODUCTS: [&str; 2] = ["billboards.bin", "shadow.png"];
/// The quality an area keeps warm when it names none: the viewer's default.
pub const DEFAULT_WARM_QUALITY: &str = "fast";

/// One play area kept warm.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WarmArea {
    /// Its name, unique in its world.
    pub name: String,
    /// Where it is: a box `[x0, y0, x1, y1]` or a polygon, world metres.
    pub area: Area,
    /// Metres added around the area at every level: tiles within this distance of it
    /// are kept warm too (0: the tiles the area itself touches).
    pub margin: f64,
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

    /// Whether the rectangle `[x0, y0, x1, y1]` (metres) comes within `margin` of the
    /// area: shares a point with it, or lies at most `margin` from its edge.
    pub fn reaches(&self, rect: [f64; 4]) -> bool {
        let m = self.margin;
        let [x0, y0, x1, y1] = rect;
        let [a0, b0, a1, b1] = self.bounds();
        // Outside the bounding box grown by the margin, nothing of the area is near.
        if x1 < a0 - m || a1 + m < x0 || y1 < b0 - m || b1 + m < y0 {
            return false;
        }
        match &self.area {
            // A box grown by the margin is near wherever its bounding box is (its
            // rounded corners aside: at most a margin's worth more, which is harmless).
            Area::Box(_) => true,
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

    fn area(area: Area, margin: f64) -> WarmArea {
        WarmArea {
            name: "town".into(),
            area,
            margin,
            levels: vec![0],
            products: vec![],
            qualities: vec![],
            layers: vec![0],
        }
    }

    #[test]
    fn a_box_reaches_the_rectangles_it_overlaps_or_comes_near() {
        let a = area(Area::Box([0.0, 0.0, 1000.0, 1000.0]), 0.0);
        assert!(a.reaches([500.0, 500.0, 2000.0, 2000.0]));
        assert!(a.reaches([-10.0, -10.0, 2000.0, 2000.0]));
        assert!(!a.reaches([1100.0, 0.0, 2000.0, 1000.0]));
        let near = area(Area::Box([0.0, 0.0, 1000.0, 1000.0]), 200.0);
        assert!(near.reaches([1100.0, 0.0, 2000.0, 1000.0]));
        assert!(!near.reaches([1300.0, 0.0, 2000.0, 1000.0]));
    }

    #[test]
    fn a_polygon_reaches_what_it_crosses_holds_or_is_held_by() {
        // A triangle with its right angle at the origin: the far corner of its bounding
        // box is outside it.
        let triangle = || Area::Polygon(Polygon::new(vec![[0.0, 0.0], [10_000.0, 0.0], [0.0, 10_000.0]]));
        let a = area(triangle(), 0.0);
        // Holds the rectangle.
        assert!(a.reaches([1000.0, 1000.0, 2000.0, 2000.0]));
        // Is held by it.
        assert!(a.reaches([-1.0, -1.0, 20_000.0, 20_000.0]));
        // An edge crosses it (no vertex inside, no corner inside).
        assert!(a.reaches([4000.0, -100.0, 4500.0, 100.0]));
        // In the bounding box, beyond the hypotenuse.
        let beyond = [8000.0, 8000.0, 9000.0, 9000.0];
        assert!(!a.reaches(beyond));
        // ...which is 6000/√2 − ... from it: about 4243 m from (8000, 8000) to the line.
        assert!(area(triangle(), 4300.0).reaches(beyond));
        assert!(!area(triangle(), 4200.0).reaches(beyond));
        // Far outside the bounding box.
        assert!(!area(triangle(), 1000.0).reaches([20_000.0, 0.0, 30_000.0, 100.0]));
    }
}
