//! Temporal coherence, measured in each level's own wind frame (so advection is
//! not counted as change): the fraction of cells whose cloud bit flips between
//! consecutive steps stays small, and an epoch boundary flips no more than an
//! ordinary step.

use cloudscape_core::automaton::{LayerSim, Rect};
use cloudscape_core::density::exact::frame_cells;
use cloudscape_core::world::Config;

fn changed(a: &[Vec<u8>], b: &[Vec<u8>]) -> f64 {
    let (mut diff, mut total) = (0usize, 0usize);
    for (x, y) in a.iter().zip(b) {
        diff += x.iter().zip(y).filter(|(p, q)| p != q).count();
        total += x.len();
    }
    diff as f64 / total as f64
}

#[test]
fn consecutive_steps_change_few_cells_and_epoch_boundaries_no_more() {
    let world = Config::embedded().world("default").unwrap();
    let sim = LayerSim::new(&world, 0);
    let e = world.layers[0].epoch;
    let windows: Vec<Rect> = (0..sim.depth())
        .map(|_| Rect {
            x0: -64,
            x1: 64,
            y0: -64,
            y1: 64,
        })
        .collect();
    let (first, last) = (3 * e.length as i64 - 4, 5 * e.length as i64 + 2);
    let states: Vec<_> = (first..=last).map(|n| frame_cells(&sim, n, &windows)).collect();
    let cloudy = states[0].iter().flatten().filter(|&&c| c == 1).count() as f64
        / states[0].iter().map(|v| v.len()).sum::<usize>() as f64;
    assert!(cloudy > 0.05, "the window has cloud ({cloudy})");
    let mut ordinary: f64 = 0.0;
    let mut boundary: f64 = 0.0;
    for (i, pair) in states.windows(2).enumerate() {
        let n = first + i as i64 + 1;
        let c = changed(&pair[0], &pair[1]);
        let in_fade = n.rem_euclid(e.length as i64) == 0;
        if in_fade {
            boundary = boundary.max(c)
        } else {
            ordinary = ordinary.max(c)
        }
        println!(
            "step {n}: {:.4} changed{}",
            c,
            if in_fade { " (epoch boundary)" } else { "" }
        );
    }
    println!("max ordinary {ordinary:.4}, max boundary {boundary:.4}");
    // Measured for the default stratocumulus layer: about 0.02 per step (see BENCHMARKS.md).
    assert!(ordinary < 0.035, "ordinary steps change {ordinary}");
    assert!(
        boundary <= ordinary * 1.25,
        "boundary {boundary} vs ordinary {ordinary}"
    );
}

fn correlation(a: &[f32], b: &[f32]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (
        a.iter().map(|&v| v as f64).sum::<f64>() / n,
        b.iter().map(|&v| v as f64).sum::<f64>() / n,
    );
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (&x, &y) in a.iter().zip(b) {
        let (dx, dy) = (x as f64 - ma, y as f64 - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    sab / (saa * sbb).sqrt()
}

#[test]
fn cloud_masses_travel_with_the_wind_at_their_height() {
    use cloudscape_core::density::{Region, density};
    let world = Config::embedded().world("default").unwrap();
    let layer = &world.layers[0];
    let (t0, dt) = (5000.0, 200.0);
    let a = Region {
        x0: 0,
        y0: 0,
        cols: 128,
        rows: 128,
    };
    let before = density(&world, 0, 0, a, t0).unwrap();
    for k in [0usize, 9] {
        let w = layer.wind_at_level(k as u32);
        let (sx, sy) = (
            (w[0] * dt / layer.cell_size).round() as i64,
            (w[1] * dt / layer.cell_size).round() as i64,
        );
        let moved = Region {
            x0: a.x0 + sx,
            y0: a.y0 + sy,
            ..a
        };
        let after_moved = density(&world, 0, 0, moved, t0 + dt).unwrap();
        let after_still = density(&world, 0, 0, a, t0 + dt).unwrap();
        let plane = |g: &cloudscape_core::density::Grid<f32>| g.data[k * 128 * 128..(k + 1) * 128 * 128].to_vec();
        let followed = correlation(&plane(&before), &plane(&after_moved));
        let stayed = correlation(&plane(&before), &plane(&after_still));
        println!(
            "level {k}: shift ({sx}, {sy}) cells: correlation {followed:.3} following the wind, {stayed:.3} standing still"
        );
        assert!(
            followed > 0.6,
            "level {k}: the cloud mass is found downwind ({followed})"
        );
        assert!(
            followed > stayed + 0.2,
            "level {k}: following the wind beats standing still"
        );
    }
}
