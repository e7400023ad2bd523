//! Where the sun is: parsed from `AZ,EL`, derived from the world clock, and
//! bucketed so pre-shaded products can be cached per sun direction.

use super::ParseError;
use crate::world::SunConfig;

/// Width of a sun-direction bucket away from the horizon, degrees of arc (elevation
/// bands above 16° and below −8°, and azimuth bands measured along a band's centre
/// circle).
pub const BUCKET_DEGREES: f64 = 8.0;

/// Edges of the elevation bands, degrees, ascending: 8° bands, narrowing toward the
/// horizon to 1° between −1° and 4°. Near the horizon the sunlight's path through the
/// air (its colour and brightness) and through a layer (its shadows) changes fastest:
/// at 1° the sun's air mass is about 27, at 4° about 13, so an 8° band lit by its 4°
/// centre makes a sunset two to four times too bright. 1° there keeps that within the
/// error of the fast presets.
pub const ELEVATION_EDGES: [f64; 33] = [
    -90.0, -88.0, -80.0, -72.0, -64.0, -56.0, -48.0, -40.0, -32.0, -24.0, -16.0, -8.0, -4.0, -2.0, -1.0, 0.0, 1.0, 2.0,
    3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 40.0, 48.0, 56.0, 64.0, 72.0, 80.0, 88.0,
];

/// Index of the first elevation band above the horizon (the band `[0°, 1°)`).
const HORIZON_BAND: i32 = 15;

/// A sun position: azimuth clockwise from north, elevation above the horizon, degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sun {
    /// Degrees clockwise from north (+y), normalised to [0, 360).
    pub azimuth_deg: f64,
    /// Degrees above the horizon, within [-90, 90].
    pub elevation_deg: f64,
}

/// A sun-direction bucket: the cache-key part of every pre-shaded product.
///
/// Bucketing (Harris & Lastra relight when the sun moves; we relight per ~8°, finer
/// near the horizon): elevation bands are the intervals between
/// [`ELEVATION_EDGES`] (the last, `[88°, 90°]`, holds the zenith), numbered so that
/// band 0 is `[0°, 1°)` and negative bands lie below the horizon (so the horizon is a
/// band edge: a sun just below it is never shaded as if above it); within a band, the
/// azimuth circle is cut into `n = max(1, round(360 · cos(el_c) / 8))` equal bands,
/// where `el_c` is the band's centre elevation, so every bucket spans at most about 8°
/// of arc.
/// Products are shaded with the bucket's centre sun, so every sun within a bucket
/// gives identical bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SunBucket {
    /// Elevation band index, −15..=17: 0 is `[0°, 1°)`, negative below the horizon.
    pub elevation_band: i32,
    /// Azimuth band index within the elevation band, 0..azimuth_bands.
    pub azimuth_band: u32,
    /// Number of azimuth bands in this elevation band.
    pub azimuth_bands: u32,
}

impl Sun {
    /// A sun from azimuth and elevation in degrees; `None` unless both are finite
    /// and the elevation lies within [-90, 90]. The azimuth is wrapped to [0, 360).
    pub fn new(azimuth_deg: f64, elevation_deg: f64) -> Option<Sun> {
        if !(azimuth_deg.is_finite() && elevation_deg.is_finite() && (-90.0..=90.0).contains(&elevation_deg)) {
            return None;
        }
        let mut az = azimuth_deg.rem_euclid(360.0);
        if az >= 360.0 {
            az = 0.0;
        }
        Some(Sun {
            azimuth_deg: az,
            elevation_deg,
        })
    }

    /// Parses `AZ,EL` (degrees).
    pub fn parse(s: &str) -> Result<Sun, ParseError> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let nums: Vec<f64> = parts.iter().filter_map(|p| p.parse::<f64>().ok()).collect();
        if parts.len() != 2 || nums.len() != 2 {
            return Err(ParseError::SunSyntax(s.to_string()));
        }
        Sun::new(nums[0], nums[1]).ok_or_else(|| ParseError::SunRange(s.to_string()))
    }

    /// The sun of the world clock: time of day `t mod 86400` s taken as local solar
    /// time, at `config.latitude` on `config.day_of_year`.
    ///
    /// Declination: Cooper 1969, `δ = 23.44° · sin(360° · (284 + N) / 365)`.
    /// Hour angle `H = 15° · (hours − 12)`. The direction in local east/north/up is
    /// `(−cos δ sin H, sin δ cos φ − cos δ cos H sin φ, sin δ sin φ + cos δ cos H cos φ)`.
    pub fn from_clock(t: f64, config: &SunConfig) -> Sun {
        let seconds = if t.is_finite() { t.rem_euclid(86_400.0) } else { 0.0 };
        let hours = seconds / 3600.0;
        let n = config.day_of_year as f64;
        let decl = (23.44f64).to_radians() * (std::f64::consts::TAU * (284.0 + n) / 365.0).sin();
        let h = (15.0 * (hours - 12.0)).to_radians();
        let phi = config.latitude.clamp(-90.0, 90.0).to_radians();
        let east = -decl.cos() * h.sin();
        let north = decl.sin() * phi.cos() - decl.cos() * h.cos() * phi.sin();
        let up = decl.sin() * phi.sin() + decl.cos() * h.cos() * phi.cos();
        let el = up.clamp(-1.0, 1.0).asin().to_degrees();
        let az = east.atan2(north).to_degrees();
        Sun::new(az, el.clamp(-90.0, 90.0)).unwrap_or(Sun {
            azimuth_deg: 180.0,
            elevation_deg: 0.0,
        })
    }

    /// Unit vector pointing toward the sun (x east, y north, z up).
    pub fn direction(&self) -> [f64; 3] {
        let (az, el) = (self.azimuth_deg.to_radians(), self.elevation_deg.to_radians());
        [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()]
    }

    /// The bucket this sun falls in.
    pub fn bucket(&self) -> SunBucket {
        let below = ELEVATION_EDGES[1..]
            .iter()
            .take_while(|&&edge| self.elevation_deg >= edge)
            .count() as i32;
        let e = below - HORIZON_BAND;
        let n = azimuth_bands(e);
        let a = ((self.azimuth_deg / 360.0 * n as f64).floor() as i64).rem_euclid(n as i64) as u32;
        SunBucket {
            elevation_band: e,
            azimuth_band: a,
            azimuth_bands: n,
        }
    }
}

fn band_centre_elevation(e: i32) -> f64 {
    let i = (e + HORIZON_BAND).clamp(0, ELEVATION_EDGES.len() as i32 - 1) as usize;
    let top = ELEVATION_EDGES.get(i + 1).copied().unwrap_or(90.0);
    0.5 * (ELEVATION_EDGES[i] + top)
}

fn azimuth_bands(e: i32) -> u32 {
    let c = band_centre_elevation(e).to_radians().cos();
    ((360.0 * c / BUCKET_DEGREES).round() as u32).max(1)
}

impl SunBucket {
    /// The sun at the centre of the bucket: what pre-shaded products are lit by.
    pub fn centre(&self) -> Sun {
        let az = (self.azimuth_band as f64 + 0.5) * 360.0 / self.azimuth_bands as f64;
        Sun {
            azimuth_deg: az,
            elevation_deg: band_centre_elevation(self.elevation_band),
        }
    }

    /// A short stable id for cache keys and manifests, e.g. `e20a17`
    /// (elevation band + 15, azimuth band).
    pub fn id(&self) -> String {
        format!("e{:02}a{:02}", self.elevation_band + HORIZON_BAND, self.azimuth_band)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_wraps_azimuth_and_rejects_bad_elevation() {
        let s = Sun::parse("370, 30").unwrap();
        assert!((s.azimuth_deg - 10.0).abs() < 1e-9 && s.elevation_deg == 30.0);
        assert_eq!(Sun::parse("10,91"), Err(ParseError::SunRange("10,91".into())));
        assert_eq!(Sun::parse("10"), Err(ParseError::SunSyntax("10".into())));
        assert_eq!(Sun::parse("nan,10"), Err(ParseError::SunRange("nan,10".into())));
        assert!(Sun::parse("-90,-90").is_ok());
    }

    #[test]
    fn direction_matches_conventions() {
        let east = Sun::new(90.0, 0.0).unwrap().direction();
        assert!((east[0] - 1.0).abs() < 1e-12 && east[1].abs() < 1e-12 && east[2].abs() < 1e-12);
        let zenith = Sun::new(0.0, 90.0).unwrap().direction();
        assert!((zenith[2] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn clock_noon_at_summer_solstice_45n() {
        // Hand calculation: δ(172) = 23.44·sin(360·456/365) = 23.45°·sin(449.75°)=23.44°·0.99996;
        // noon elevation = 90 − 45 + δ ≈ 68.44°, due south.
        let s = Sun::from_clock(
            12.0 * 3600.0,
            &SunConfig {
                latitude: 45.0,
                day_of_year: 172,
            },
        );
        assert!((s.elevation_deg - 68.44).abs() < 0.05, "{s:?}");
        assert!((s.azimuth_deg - 180.0).abs() < 1e-6, "{s:?}");
        // Midnight: below the horizon by 90 − 45 − δ ≈ −21.56°.
        let m = Sun::from_clock(
            86_400.0 * 3.0,
            &SunConfig {
                latitude: 45.0,
                day_of_year: 172,
            },
        );
        assert!((m.elevation_deg + 21.56).abs() < 0.05, "{m:?}");
        // Morning sun is in the east.
        let am = Sun::from_clock(
            8.0 * 3600.0,
            &SunConfig {
                latitude: 45.0,
                day_of_year: 172,
            },
        );
        assert!(am.azimuth_deg > 45.0 && am.azimuth_deg < 135.0, "{am:?}");
    }

    #[test]
    fn bands_tile_the_sphere_and_narrow_at_the_horizon() {
        // Every edge starts its own band, and the band just below starts one edge down.
        for (i, w) in ELEVATION_EDGES.windows(2).enumerate() {
            assert!(w[0] < w[1]);
            let e = i as i32 - HORIZON_BAND;
            let low = Sun::new(0.0, w[0]).unwrap().bucket();
            let mid = Sun::new(0.0, 0.5 * (w[0] + w[1])).unwrap().bucket();
            assert_eq!((low.elevation_band, mid.elevation_band), (e, e), "band {i}");
            assert_eq!(band_centre_elevation(e), 0.5 * (w[0] + w[1]));
        }
        assert_eq!(Sun::new(0.0, 90.0).unwrap().bucket().elevation_band, 17);
        assert_eq!(Sun::new(0.0, -90.0).unwrap().bucket().elevation_band, -15);
        // A sunset at 1° is lit at 1.5°, not at 4° (an 8° band's centre would be).
        assert_eq!(Sun::new(270.0, 1.0).unwrap().bucket().centre().elevation_deg, 1.5);
        // Ids stay two digits per part and distinct per bucket.
        let mut ids = std::collections::HashSet::new();
        for el in -90..=90 {
            for az in (0..360).step_by(3) {
                let b = Sun::new(az as f64, el as f64).unwrap().bucket();
                assert_eq!(b.id().len(), 6);
                ids.insert((b.id(), b));
            }
        }
        let unique: std::collections::HashSet<_> = ids.iter().map(|(id, _)| id.clone()).collect();
        assert_eq!(unique.len(), ids.len());
    }

    #[test]
    fn buckets_are_about_eight_degrees_and_stable() {
        let a = Sun::new(100.0, 30.0).unwrap().bucket();
        let b = Sun::new(101.0, 31.0).unwrap().bucket();
        assert_eq!(a, b);
        assert_eq!(a.id(), b.id());
        assert_ne!(
            Sun::new(100.0, 30.0).unwrap().bucket(),
            Sun::new(100.0, 42.0).unwrap().bucket()
        );
        // The horizon is a band edge.
        assert_ne!(
            Sun::new(0.0, -0.1).unwrap().bucket(),
            Sun::new(0.0, 0.1).unwrap().bucket()
        );
        // The centre of a bucket lies in the bucket, within ~8° of arc of any member.
        for el in [-89.0, -30.0, -0.5, 0.0, 3.0, 45.0, 80.0, 89.9, 90.0] {
            for az in [0.0, 7.9, 123.4, 359.9] {
                let s = Sun::new(az, el).unwrap();
                let c = s.bucket().centre();
                assert_eq!(c.bucket(), s.bucket(), "{s:?}");
                let (d1, d2) = (s.direction(), c.direction());
                let cos = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2];
                assert!(cos.clamp(-1.0, 1.0).acos().to_degrees() < 8.0, "{s:?} vs {c:?}");
            }
        }
    }
}
