//! Cameras shared by the stages that draw a mesh (depth images, exposure, selection,
//! evaluation, cull-eval): orthographic views framing a sphere, perspective views from a point,
//! their projections, and evenly spread view directions. Imports nothing of the pipeline.

use glam::DVec3;

#[derive(Clone, Copy, Debug)]
pub(crate) enum Lens {
    /// Framing the sphere (center, radius).
    Orthographic { center: DVec3, radius: f64 },
    /// A 90° field of view from `eye`.
    Perspective { eye: DVec3 },
}

/// A square camera of `pixels` × `pixels`.
#[derive(Clone, Debug)]
pub struct View {
    /// Unit vector from what is seen towards the camera.
    pub dir: DVec3,
    right: DVec3,
    up: DVec3,
    pub(crate) lens: Lens,
    pub pixels: usize,
    tolerance: f64,
}

impl View {
    /// An orthographic camera framing a bounding sphere, looking along `-dir`.
    pub fn new(dir: DVec3, center: DVec3, radius: f64, pixels: usize) -> View {
        let radius = radius.max(1e-12);
        let lens = Lens::Orthographic { center, radius };
        View::looking(dir, lens, pixels, 2e-4 * radius)
    }

    /// This orthographic view with `extra` more pixels on each side, at the same scale and
    /// depth tolerance: a wider frame whose pixel centres fall on this one's. Perspective views
    /// come back unchanged.
    pub fn widened(&self, extra: usize) -> View {
        let Lens::Orthographic { center, radius } = self.lens else {
            return self.clone();
        };
        let pixels = self.pixels + 2 * extra;
        let radius = radius * pixels as f64 / self.pixels as f64;
        View {
            lens: Lens::Orthographic { center, radius },
            pixels,
            ..self.clone()
        }
    }

    /// A perspective camera at `eye` with a 90° field of view, looking along `-dir`.
    /// `tolerance` is the depth tolerance of "nearer than" tests.
    pub fn perspective(eye: DVec3, dir: DVec3, pixels: usize, tolerance: f64) -> View {
        View::looking(dir, Lens::Perspective { eye }, pixels, tolerance)
    }

    /// The six faces of a cube map around `eye`.
    pub fn cube_map(eye: DVec3, pixels: usize, tolerance: f64) -> Vec<View> {
        [DVec3::X, DVec3::NEG_X, DVec3::Y, DVec3::NEG_Y, DVec3::Z, DVec3::NEG_Z]
            .into_iter()
            .map(|dir| View::perspective(eye, dir, pixels, tolerance))
            .collect()
    }

    fn looking(dir: DVec3, lens: Lens, pixels: usize, tolerance: f64) -> View {
        let dir = dir.normalize();
        let hint = if dir.y.abs() > 0.99 { DVec3::Z } else { DVec3::Y };
        let right = hint.cross(dir).normalize();
        let up = dir.cross(right);
        View {
            dir,
            right,
            up,
            lens,
            pixels,
            tolerance,
        }
    }

    /// Pixel coordinates (x, y) and depth (distance in front of the camera plane).
    #[inline]
    pub fn project(&self, p: DVec3) -> DVec3 {
        let half = self.pixels as f64 / 2.0;
        match self.lens {
            Lens::Orthographic { center, radius } => self.project_orthographic(p, center, radius, half / radius),
            Lens::Perspective { eye } => self.project_perspective(p, eye, half),
        }
    }

    /// [`View::project`] of each point, with the lens's constants worked out once.
    pub fn project_all(&self, points: impl Iterator<Item = DVec3>) -> Vec<DVec3> {
        let mut projected = Vec::new();
        self.project_into(points, &mut projected);
        projected
    }

    /// [`View::project_all`] into `projected`, whose room is kept from call to call.
    pub fn project_into(&self, points: impl Iterator<Item = DVec3>, projected: &mut Vec<DVec3>) {
        let half = self.pixels as f64 / 2.0;
        projected.clear();
        match self.lens {
            Lens::Orthographic { center, radius } => {
                let scale = half / radius;
                projected.extend(points.map(|p| self.project_orthographic(p, center, radius, scale)))
            }
            Lens::Perspective { eye } => projected.extend(points.map(|p| self.project_perspective(p, eye, half))),
        }
    }

    /// For an orthographic view, bounds of [`View::project`] over the box [lo, hi] (to within
    /// rounding); None for a perspective one.
    pub fn orthographic_box_image(&self, lo: DVec3, hi: DVec3) -> Option<(DVec3, DVec3)> {
        let Lens::Orthographic { center, radius } = self.lens else {
            return None;
        };
        let scale = self.pixels as f64 / 2.0 / radius;
        let (middle, half) = (0.5 * (lo + hi), 0.5 * (hi - lo));
        let image = self.project_orthographic(middle, center, radius, scale);
        let reach = DVec3::new(
            half.dot(self.right.abs()) * scale,
            half.dot(self.up.abs()) * scale,
            half.dot(self.dir.abs()),
        );
        Some((image - reach, image + reach))
    }

    #[inline(always)]
    fn project_orthographic(&self, p: DVec3, center: DVec3, radius: f64, scale: f64) -> DVec3 {
        let d = p - center;
        DVec3::new(
            (d.dot(self.right) + radius) * scale,
            (d.dot(self.up) + radius) * scale,
            radius - d.dot(self.dir),
        )
    }

    #[inline(always)]
    fn project_perspective(&self, p: DVec3, eye: DVec3, half: f64) -> DVec3 {
        let d = p - eye;
        let z = -d.dot(self.dir);
        DVec3::new(
            (d.dot(self.right) / z + 1.0) * half,
            (d.dot(self.up) / z + 1.0) * half,
            z,
        )
    }

    /// For a perspective view, the sides of its frustum (right, left, top, bottom) that `p` lies
    /// beyond, a bit each, with a millionth to spare; none for an orthographic view. A triangle
    /// whose corners all lie beyond one side draws no pixel: clipped at the near plane, it stays
    /// there, where [`View::project`] puts it off the image.
    pub fn beyond_sides(&self, p: DVec3) -> u8 {
        let Lens::Perspective { eye } = self.lens else {
            return 0;
        };
        let d = p - eye;
        let (across, along, z) = (d.dot(self.right), d.dot(self.up), -d.dot(self.dir));
        let beyond = |w: f64| w - z > 1e-6 * (w.abs() + z.abs());
        u8::from(beyond(across))
            | u8::from(beyond(-across)) << 1
            | u8::from(beyond(along)) << 2
            | u8::from(beyond(-along)) << 3
    }

    /// A perspective view's rays as rise (world y) per unit of depth: the most that any ray
    /// through the image rises or falls, and the most that two rays up to `apart` pixels apart
    /// along each axis differ by.
    pub fn ray_rise(&self, apart: f64) -> (f64, f64) {
        let spread = self.right.y.abs() + self.up.y.abs();
        let half = self.pixels as f64 / 2.0;
        (self.dir.y.abs() + spread, apart / half * spread)
    }

    /// The unit vector from `p` towards the camera: `dir` for orthographic views.
    pub fn towards_camera(&self, p: DVec3) -> DVec3 {
        self.line_to_camera(p).0
    }

    /// The line from `p` to the camera: [`View::towards_camera`], and how far the camera is
    /// (without end for orthographic views).
    pub fn line_to_camera(&self, p: DVec3) -> (DVec3, f64) {
        match self.lens {
            Lens::Orthographic { .. } => (self.dir, f64::INFINITY),
            Lens::Perspective { eye } => ((eye - p).normalize_or(self.dir), eye.distance(p)),
        }
    }

    /// The point at pixel `index`'s centre and `depth`: [`View::project`] undone.
    pub fn unproject(&self, index: usize, depth: f64) -> DVec3 {
        let half = self.pixels as f64 / 2.0;
        let x = (index % self.pixels) as f64 + 0.5;
        let y = (index / self.pixels) as f64 + 0.5;
        match self.lens {
            Lens::Orthographic { center, radius } => {
                let scale = radius / half;
                center
                    + self.right * (x * scale - radius)
                    + self.up * (y * scale - radius)
                    + self.dir * (radius - depth)
            }
            Lens::Perspective { eye } => {
                eye + (self.right * (x / half - 1.0) + self.up * (y / half - 1.0) - self.dir) * depth
            }
        }
    }

    /// For a GPU render of a perspective view: the matrix from points relative to `origin` to
    /// clip space, x and y as [`View::project`] has them before the divide, w the depth, and
    /// z = `near`, so that depth is near / w: reversed, with a float buffer's precision where it
    /// is needed, and compared with "greater". None for orthographic views.
    pub fn perspective_clip_matrix(&self, origin: DVec3, near: f64) -> Option<glam::DMat4> {
        let Lens::Perspective { eye } = self.lens else {
            return None;
        };
        let e = eye - origin;
        let row = |v: DVec3| glam::DVec4::new(v.x, v.y, v.z, -v.dot(e));
        let rows = [
            row(self.right),
            row(self.up),
            glam::DVec4::new(0.0, 0.0, 0.0, near),
            row(-self.dir),
        ];
        Some(glam::DMat4::from_cols_array_2d(&rows.map(|r| r.to_array())).transpose())
    }

    /// For the GPU rasterizer (shaders/raster.wgsl): three rows taking a point relative to
    /// `origin`, as (x, y, z, 1), to [`View::project`]'s pixel x, pixel y and depth. None for
    /// perspective views.
    pub fn ortho_rows(&self, origin: DVec3) -> Option<[[f64; 4]; 3]> {
        let [x, y, _, depth] = self.projection_rows(origin);
        matches!(self.lens, Lens::Orthographic { .. }).then_some([x, y, depth])
    }

    /// For the GPU (shaders/exposure.wgsl): four rows X, Y, W, Z taking a point relative to
    /// `origin`, as (x, y, z, 1), to [`View::project`]'s pixel (X / W, Y / W) and depth Z. W is 1
    /// for an orthographic view and the depth for a perspective one.
    pub fn projection_rows(&self, origin: DVec3) -> [[f64; 4]; 4] {
        let row = |axis: DVec3, scale: f64, constant: f64| {
            let v = axis * scale;
            [v.x, v.y, v.z, constant]
        };
        let half = self.pixels as f64 / 2.0;
        match self.lens {
            Lens::Orthographic { center, radius } => {
                let scale = half / radius;
                let offset = origin - center;
                [
                    row(self.right, scale, (offset.dot(self.right) + radius) * scale),
                    row(self.up, scale, (offset.dot(self.up) + radius) * scale),
                    [0.0, 0.0, 0.0, 1.0],
                    row(-self.dir, 1.0, radius - offset.dot(self.dir)),
                ]
            }
            Lens::Perspective { eye } => {
                let offset = origin - eye;
                let depth = row(-self.dir, 1.0, -offset.dot(self.dir));
                // Pixel x = (right · d / depth + 1) · half, so X = half · (right · d + depth).
                let numerator = |axis: DVec3| {
                    let r = row(axis, 1.0, offset.dot(axis));
                    [0, 1, 2, 3].map(|k| half * (r[k] + depth[k]))
                };
                [numerator(self.right), numerator(self.up), depth, depth]
            }
        }
    }

    /// Pixels per unit of length of an orthographic view; None for perspective views.
    pub fn ortho_scale(&self) -> Option<f64> {
        match self.lens {
            Lens::Orthographic { radius, .. } => Some(self.pixels as f64 / 2.0 / radius),
            Lens::Perspective { .. } => None,
        }
    }

    /// The depth tolerance of "nearer than" tests: 1e-4 of the framed diameter.
    pub fn depth_tolerance(&self) -> f64 {
        self.tolerance
    }
}

/// `n` unit directions evenly spread over the sphere; y is up.
pub fn fibonacci_sphere(n: usize) -> Vec<DVec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - (2 * i + 1) as f64 / n as f64;
            let r = (1.0 - y * y).sqrt();
            let phi = golden * i as f64;
            DVec3::new(r * phi.cos(), y, r * phi.sin())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::View;
    use crate::geom::raster::rasterize;
    use glam::DVec3;

    #[test]
    fn a_triangle_beyond_a_side_of_a_perspective_view_draws_nothing() {
        let mut rng = fastrand::Rng::with_seed(5);
        let eye = DVec3::new(0.3, -0.2, 0.1);
        let views = View::cube_map(eye, 32, 1e-4);
        let (mut beyond, mut drawn) = (0, 0);
        for _ in 0..20_000 {
            // Corners near the eye and far, some behind it, so that clipping cuts many.
            let tri = [(); 3].map(|()| eye + DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 4.0 - 2.0);
            for view in &views {
                let sides = tri.iter().fold(0xf, |sides, &p| sides & view.beyond_sides(p));
                let mut pixels = 0;
                rasterize(view, &tri, |_, _| pixels += 1);
                if sides != 0 {
                    beyond += 1;
                    assert_eq!(pixels, 0, "{tri:?} beyond sides {sides:#b}");
                }
                drawn += usize::from(pixels > 0);
            }
        }
        // Both kinds are common, so the test says something.
        assert!(beyond > 20_000 && drawn > 20_000, "{beyond} beyond, {drawn} drawn");
    }

    #[test]
    fn projection_rows_project_as_the_view_does() {
        let origin = DVec3::new(0.5, 0.25, -1.0);
        let views = [
            View::new(DVec3::new(0.2, 0.9, -0.4), DVec3::new(1.0, 2.0, 3.0), 5.0, 64),
            View::perspective(DVec3::new(0.3, -1.0, 2.0), DVec3::new(-0.5, 0.1, 0.8), 64, 1e-3),
        ];
        for view in views {
            let rows = view.projection_rows(origin);
            for p in [DVec3::new(1.0, 2.0, 3.0), DVec3::new(-0.7, -2.0, 0.4)] {
                let h = (p - origin).extend(1.0);
                let [x, y, w, z] = rows.map(|r| glam::DVec4::from_array(r).dot(h));
                let q = view.project(p);
                assert!(DVec3::new(x / w, y / w, z).distance(q) < 1e-9, "{q}");
            }
        }
    }

    #[test]
    fn unproject_undoes_project_at_pixel_centres() {
        let eye = DVec3::new(0.3, -1.0, 2.0);
        let views = [
            View::new(DVec3::new(0.2, 0.9, -0.4), DVec3::new(1.0, 2.0, 3.0), 5.0, 64),
            View::perspective(eye, DVec3::new(-0.5, 0.1, 0.8), 64, 1e-3),
        ];
        for view in views {
            for (index, depth) in [(0, 0.5), (64 * 31 + 17, 2.0), (64 * 64 - 1, 7.5)] {
                let q = view.project(view.unproject(index, depth));
                let centre = DVec3::new((index % 64) as f64 + 0.5, (index / 64) as f64 + 0.5, depth);
                assert!(q.distance(centre) < 1e-9, "{q} against {centre}");
            }
        }
    }
}
