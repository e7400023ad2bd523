//! Where the sun is: parsed from `AZ,EL`, derived from the world clock, and
//! bucketed so pre-shaded products can be cached per sun direction.

use crate::world::SunConfig;

/// Width of a sun-direction bucket, degrees of arc (elevation bands, and azimuth
/// bands measured along the band's centre circle).
pub const BUCKET_DEGREES: f64 = 8.0;

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
/// Bucketing (Harris & Lastra relight when the sun moves; we relight per ~8°):
/// elevation bands are `[8e, 8e + 8)` degrees for `e = floor(el / 8)` (so the horizon
/// is a band edge: a sun just below it is never shaded as if above it); within a band,
/// the azimuth circle is cut into `n = max(1, round(360 · cos(el_c) / 8))` equal bands,
/// where `el_c` is the band's centre elevation, so every bucket spans about 8° of arc.
/// Products are shaded with the bucket's centre sun, so every sun within a bucket
/// gives identical bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SunBucket {
    /// Elevation band index, -12..=11.
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
    pub fn parse(s: &str) -> Result<Sun, String> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let nums: Vec<f64> = parts.iter().filter_map(|p| p.parse::<f64>().ok()).collect();
        if parts.len() != 2 || nums.len() != 2 {
            return Err(format!("sun must be AZ,EL in degrees, got `{s}`"));
        }
        Sun::new(nums[0], nums[1])
            .ok_or_else(|| format!("sun must have a finite azimuth and an elevation within [-90, 90], got `{s}`"))
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
        let e = ((self.elevation_deg / BUCKET_DEGREES).floor() as i32).clamp(-12, 11);
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
    ((e as f64 + 0.5) * BUCKET_DEGREES).clamp(-90.0, 90.0)
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

    /// A short stable id for cache keys and manifests, e.g. `e05a17`
    /// (elevation band + 12, azimuth band).
    pub fn id(&self) -> String {
        format!("e{:02}a{:02}", self.elevation_band + 12, self.azimuth_band)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_wraps_azimuth_and_rejects_bad_elevation() {
        let s = Sun::parse("370, 30").unwrap();
        assert!((s.azimuth_deg - 10.0).abs() < 1e-9 && s.elevation_deg == 30.0);
        assert!(Sun::parse("10,91").is_err());
        assert!(Sun::parse("10").is_err());
        assert!(Sun::parse("nan,10").is_err());
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
