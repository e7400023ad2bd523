//! Cameras and views: where rays start and where billboards land on screen.

use super::ParseError;
use super::light::dot;
use super::shade::cross;

/// A camera: `X,Y,Z,YAW,PITCH,FOV` (PRODUCT.md): position in world metres, yaw in
/// degrees clockwise from north (+y), pitch in degrees above the horizon, FOV the
/// horizontal field of view in degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position, world metres (x east, y north, z up).
    pub position: [f64; 3],
    /// Heading, degrees clockwise from north.
    pub yaw_deg: f64,
    /// Degrees above the horizon.
    pub pitch_deg: f64,
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
}

/// Largest accepted |coordinate| of a camera position, metres.
pub const MAX_CAMERA_COORD: f64 = 1e12;

impl Camera {
    /// Parses `X,Y,Z,YAW,PITCH,FOV`. Pitch must lie in [-90, 90], FOV in [1, 170],
    /// the position within ±1e12 m.
    pub fn parse(s: &str) -> Result<Camera, ParseError> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let nums: Vec<f64> = parts
            .iter()
            .filter_map(|p| p.parse::<f64>().ok())
            .filter(|v| v.is_finite())
            .collect();
        if parts.len() != 6 || nums.len() != 6 {
            return Err(ParseError::CameraSyntax(s.to_string()));
        }
        Camera::new([nums[0], nums[1], nums[2]], nums[3], nums[4], nums[5])
    }

    /// A checked camera.
    pub fn new(position: [f64; 3], yaw_deg: f64, pitch_deg: f64, fov_deg: f64) -> Result<Camera, ParseError> {
        if !position.iter().all(|v| v.is_finite() && v.abs() <= MAX_CAMERA_COORD) {
            return Err(ParseError::CameraPosition);
        }
        if !(pitch_deg.is_finite() && (-90.0..=90.0).contains(&pitch_deg)) {
            return Err(ParseError::CameraPitch(pitch_deg));
        }
        if !(fov_deg.is_finite() && (1.0..=170.0).contains(&fov_deg)) {
            return Err(ParseError::CameraFov(fov_deg));
        }
        if !yaw_deg.is_finite() {
            return Err(ParseError::CameraYaw);
        }
        Ok(Camera {
            position,
            yaw_deg,
            pitch_deg,
            fov_deg,
        })
    }

    /// (forward, right, up) unit vectors.
    pub fn basis(&self) -> ([f64; 3], [f64; 3], [f64; 3]) {
        let (yaw, pitch) = (self.yaw_deg.to_radians(), self.pitch_deg.to_radians());
        let forward = [yaw.sin() * pitch.cos(), yaw.cos() * pitch.cos(), pitch.sin()];
        let right = [yaw.cos(), -yaw.sin(), 0.0];
        let up = cross(right, forward);
        (forward, right, up)
    }
}

/// A view: a camera with an image size (perspective), or an orthographic view
/// (impostors, tests).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Eye (perspective) or image centre (orthographic), world metres.
    pub origin: [f64; 3],
    /// Unit vector along the view axis.
    pub forward: [f64; 3],
    /// Unit vector toward the image's right.
    pub right: [f64; 3],
    /// Unit vector toward the image's top.
    pub up: [f64; 3],
    /// Perspective or orthographic projection.
    pub kind: ViewKind,
}

/// How a [`View`] projects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ViewKind {
    /// A pinhole at the view's origin.
    Perspective {
        /// Focal length in pixels.
        focal: f64,
    },
    /// Parallel rays through the image plane.
    Orthographic {
        /// Metres per pixel.
        metres_per_pixel: f64,
    },
}

/// Where a point lands on screen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projected {
    /// Pixel coordinates (x right, y down; pixel centres at i + 0.5).
    pub x: f64,
    /// Pixel y (down).
    pub y: f64,
    /// Distance along the forward axis, metres.
    pub depth: f64,
    /// Pixels per metre at that depth.
    pub scale: f64,
}

impl View {
    /// The view of `camera` on a `width × height` image.
    pub fn perspective(camera: &Camera, width: usize, height: usize) -> View {
        let (forward, right, up) = camera.basis();
        let focal = width as f64 / 2.0 / (camera.fov_deg.to_radians() / 2.0).tan();
        View {
            width,
            height,
            origin: camera.position,
            forward,
            right,
            up,
            kind: ViewKind::Perspective { focal },
        }
    }

    /// An orthographic view centred on `centre`, looking along `forward` (unit),
    /// with `up` the screen's up (unit, perpendicular to forward).
    pub fn orthographic(
        centre: [f64; 3],
        forward: [f64; 3],
        up: [f64; 3],
        metres_per_pixel: f64,
        width: usize,
        height: usize,
    ) -> View {
        let right = cross(forward, up);
        View {
            width,
            height,
            origin: centre,
            forward,
            right,
            up,
            kind: ViewKind::Orthographic { metres_per_pixel },
        }
    }

    /// The ray through pixel coordinates (`px`, `py`): origin and unit direction.
    pub fn ray(&self, px: f64, py: f64) -> ([f64; 3], [f64; 3]) {
        let sx = px - self.width as f64 / 2.0;
        let sy = self.height as f64 / 2.0 - py;
        match self.kind {
            ViewKind::Perspective { focal } => {
                let d = [0, 1, 2].map(|i| self.forward[i] * focal + self.right[i] * sx + self.up[i] * sy);
                let n = dot(d, d).sqrt();
                (self.origin, d.map(|c| c / n))
            }
            ViewKind::Orthographic { metres_per_pixel: m } => {
                let o = [0, 1, 2]
                    .map(|i| self.origin[i] + (self.right[i] * sx + self.up[i] * sy) * m - self.forward[i] * 1e6);
                (o, self.forward)
            }
        }
    }

    /// Where `p` lands; `None` behind the eye (perspective) or not finite.
    pub fn project(&self, p: [f64; 3]) -> Option<Projected> {
        let r = [p[0] - self.origin[0], p[1] - self.origin[1], p[2] - self.origin[2]];
        let (x, y, depth) = (dot(r, self.right), dot(r, self.up), dot(r, self.forward));
        let scale = match self.kind {
            ViewKind::Perspective { focal } => {
                if !(depth > 0.0) {
                    return None;
                }
                focal / depth
            }
            ViewKind::Orthographic { metres_per_pixel } => 1.0 / metres_per_pixel,
        };
        let out = Projected {
            x: self.width as f64 / 2.0 + x * scale,
            y: self.height as f64 / 2.0 - y * scale,
            depth,
            scale,
        };
        if out.x.is_finite() && out.y.is_finite() && out.scale.is_finite() {
            Some(out)
        } else {
            None
        }
    }

    /// Unit direction from the eye toward `p` (the view direction for orthographic views).
    pub fn direction_to(&self, p: [f64; 3]) -> [f64; 3] {
        match self.kind {
            ViewKind::Perspective { .. } => {
                let r = [p[0] - self.origin[0], p[1] - self.origin[1], p[2] - self.origin[2]];
                let n = dot(r, r).sqrt();
                if n > 0.0 { r.map(|c| c / n) } else { self.forward }
            }
            ViewKind::Orthographic { .. } => self.forward,
        }
    }

    /// Distance used to sort billboards back to front.
    pub fn sort_distance(&self, p: [f64; 3]) -> f64 {
        let r = [p[0] - self.origin[0], p[1] - self.origin[1], p[2] - self.origin[2]];
        match self.kind {
            ViewKind::Perspective { .. } => dot(r, r).sqrt(),
            ViewKind::Orthographic { .. } => dot(r, self.forward),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaw_ninety_looks_east_and_projection_inverts_rays() {
        let cam = Camera::parse("0,0,100,90,0,60").unwrap();
        let (f, r, u) = cam.basis();
        assert!((f[0] - 1.0).abs() < 1e-12 && f[1].abs() < 1e-12);
        assert!((r[1] + 1.0).abs() < 1e-12, "right of east-facing is south: {r:?}");
        assert!((u[2] - 1.0).abs() < 1e-12);
        let view = View::perspective(&cam, 64, 48);
        let (o, d) = view.ray(10.5, 30.5);
        let p = [o[0] + d[0] * 500.0, o[1] + d[1] * 500.0, o[2] + d[2] * 500.0];
        let q = view.project(p).unwrap();
        assert!((q.x - 10.5).abs() < 1e-9 && (q.y - 30.5).abs() < 1e-9);
        assert!(view.project([-10.0, 0.0, 100.0]).is_none());
    }

    #[test]
    fn bad_cameras_are_refused() {
        assert_eq!(Camera::parse("0,0,0,0,91,60"), Err(ParseError::CameraPitch(91.0)));
        assert_eq!(Camera::parse("0,0,0,0,0,0"), Err(ParseError::CameraFov(0.0)));
        assert_eq!(
            Camera::parse("0,0,0,0,0"),
            Err(ParseError::CameraSyntax("0,0,0,0,0".into()))
        );
        assert!(matches!(
            Camera::parse("0,0,inf,0,0,60"),
            Err(ParseError::CameraSyntax(_))
        ));
        assert_eq!(
            Camera::new([2e12, 0.0, 0.0], 0.0, 0.0, 60.0),
            Err(ParseError::CameraPosition)
        );
        assert_eq!(Camera::new([0.0; 3], f64::NAN, 0.0, 60.0), Err(ParseError::CameraYaw));
        assert_eq!(
            ParseError::CameraPitch(91.0).to_string(),
            "camera pitch must be within [-90, 90] degrees, got 91"
        );
        assert!(Camera::parse("0,0,0,0,90,60").is_ok());
    }
}
