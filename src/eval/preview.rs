//! Preview sheets: the occluder over its original, as a technical artist judges it. Four views
//! (front, side, top, three-quarter) of the original shaded in grey, with the occluder over it in
//! a translucent colour per kind of piece, false pixels in red, and a caption.

use crate::geom::camera::View;
use crate::geom::raster::rasterize;
use crate::mesh::Mesh;
use crate::occluder::{Occluder, Shape};
use glam::DVec3;
use image::{Rgb, RgbImage};

/// What the caption says.
pub struct Caption {
    /// The mesh's name.
    pub name: String,
    pub triangles_in: usize,
    pub triangles_out: usize,
    /// Coverage and false pixels from the report's evaluation, with its view count; None: the
    /// sheet's own four views give them, and the caption says so.
    pub judged: Option<(f64, u64, usize)>,
    /// The loops of openings that `cook.smallest_hole` counted as closed: outlined in every
    /// view, and named in the legend.
    pub openings: Vec<Vec<[f64; 3]>>,
}

/// The pixels of one view's side.
pub const VIEW_PIXELS: usize = 320;
/// Height of the caption strip.
pub(crate) const CAPTION_PIXELS: u32 = 64;
pub(crate) const BACKGROUND: Rgb<u8> = Rgb([246, 246, 242]);
pub(crate) const FALSE_PIXEL: Rgb<u8> = Rgb([220, 20, 30]);
const TEXT: Rgb<u8> = Rgb([30, 30, 36]);
const OUTLINE: Rgb<u8> = Rgb([200, 0, 200]);

/// The kinds of piece an occluder is drawn in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Piece {
    Boxes,
    Quads,
    Patches,
    /// Flat regions of the surface itself.
    Surface,
    /// Double-sided rectangles whose kind is not known (read back from a GLB).
    Panels,
    /// A mesh judged as a whole (any occluder, ours or not).
    Solid,
}

impl Piece {
    fn name(self) -> &'static str {
        match self {
            Piece::Boxes => "boxes",
            Piece::Quads => "quads",
            Piece::Patches => "patches",
            Piece::Surface => "surface pieces",
            Piece::Panels => "panels",
            Piece::Solid => "occluder",
        }
    }

    fn colour(self) -> [f64; 3] {
        match self {
            Piece::Boxes | Piece::Solid => [40.0, 110.0, 230.0],
            Piece::Quads | Piece::Panels => [30.0, 170.0, 90.0],
            Piece::Patches => [235.0, 150.0, 20.0],
            Piece::Surface => [225.0, 205.0, 40.0],
        }
    }
}

/// A triangle of the occluder and its kind of piece.
pub type PieceTriangle = ([DVec3; 3], Piece);

/// The triangles of a cooked occluder, each with its kind.
pub fn pieces(occluder: &Occluder) -> Vec<PieceTriangle> {
    let solid = occluder.solid.triangles_f64().map(|t| (t, Piece::Boxes));
    let panels = occluder.panels.iter().flat_map(|p| {
        let piece = match p.shape {
            Shape::Boxes => Piece::Boxes,
            Shape::Quads => Piece::Quads,
            Shape::Patches => Piece::Patches,
            Shape::Surface => Piece::Surface,
        };
        p.triangles().map(|t| (t, piece))
    });
    let pieces = occluder
        .pieces
        .iter()
        .flat_map(|p| &p.triangles)
        .map(|t| (t.map(DVec3::from_array), Piece::Surface));
    solid.chain(panels).chain(pieces).collect()
}

/// The triangles of a mesh, all of one kind.
pub fn pieces_of_mesh(mesh: &Mesh, piece: Piece) -> Vec<PieceTriangle> {
    mesh.triangles_f64().map(|t| (t, piece)).collect()
}

/// The four views: name and direction towards the camera (y up).
const VIEWS: [(&str, [f64; 3]); 4] = [
    ("front", [0.0, 0.0, 1.0]),
    ("side", [1.0, 0.0, 0.0]),
    ("top", [0.0, 1.0, 0.0]),
    ("three-quarter", [1.0, 0.8, 1.0]),
];

/// The sheet, and the false pixels counted in its four views.
pub fn sheet(original: &Mesh, occluder: &[PieceTriangle], caption: &Caption) -> (RgbImage, u64) {
    // The union's frame: an occluder sticking out sideways shows too.
    let (center, radius) = union_sphere(original, occluder);
    let side = VIEW_PIXELS as u32;
    let mut image = RgbImage::from_pixel(2 * side, 2 * side + CAPTION_PIXELS, BACKGROUND);
    let (mut false_pixels, mut covered, mut seen) = (0u64, 0u64, 0u64);
    for (i, (name, dir)) in VIEWS.iter().enumerate() {
        let view = View::new(DVec3::from_array(*dir).normalize(), center, radius, VIEW_PIXELS);
        let mut drawn = draw_view(&view, original, occluder);
        outline(&view, &mut drawn.pixels, &caption.openings);
        false_pixels += drawn.false_pixels;
        covered += drawn.covered;
        seen += drawn.seen;
        place_view(&mut image, i, &drawn.pixels, name);
    }
    let figures = match caption.judged {
        Some((coverage, false_pixels, views)) => {
            format!(
                "coverage {:.1}%, {false_pixels} false pixels ({views} views)",
                coverage * 100.0
            )
        }
        None => format!(
            "coverage {:.1}%, {false_pixels} false pixels (these 4 views)",
            100.0 * covered as f64 / seen.max(1) as f64
        ),
    };
    let y = 2 * side + 8;
    let mut kinds: Vec<Piece> = occluder.iter().map(|t| t.1).collect();
    kinds.sort_by_key(|k| *k as u8);
    kinds.dedup();
    let entries: Vec<(&str, [f64; 3])> = kinds
        .iter()
        .map(|k| (k.name(), k.colour()))
        .chain([("false", FALSE_PIXEL.0.map(f64::from))])
        .chain((!caption.openings.is_empty()).then_some(("closed", OUTLINE.0.map(f64::from))))
        .collect();
    let legend_left = legend(&mut image, 2 * side - 8, y, &entries);
    // The name up to the legend; the rest of a long name is left out.
    let fits = (legend_left.saturating_sub(16) / 16) as usize;
    text(
        &mut image,
        8,
        y,
        2,
        &caption.name.chars().take(fits).collect::<String>(),
    );
    let triangles = format!("{} -> {} triangles", caption.triangles_in, caption.triangles_out);
    text(&mut image, 8, y + 22, 2, &triangles);
    text(&mut image, 8, y + 44, 1, &figures);
    (image, false_pixels)
}

/// Draws each loop of `loops` over a view's pixels (rows from the top), one pixel wide.
fn outline(view: &View, pixels: &mut [Rgb<u8>], loops: &[Vec<[f64; 3]>]) {
    let n = view.pixels as f64;
    for points in loops {
        for (k, a) in points.iter().enumerate() {
            let b = points[(k + 1) % points.len()];
            let (a, b) = (view.project(DVec3::from_array(*a)), view.project(DVec3::from_array(b)));
            let steps = (b.x - a.x).abs().max((b.y - a.y).abs()).ceil().clamp(1.0, 4.0 * n) as usize;
            for s in 0..=steps {
                let p = a + (b - a) * (s as f64 / steps as f64);
                if (0.0..n).contains(&p.x) && (0.0..n).contains(&p.y) {
                    // Raster rows run bottom-up; image rows top-down.
                    let row = view.pixels - 1 - p.y as usize;
                    pixels[row * view.pixels + p.x as usize] = OUTLINE;
                }
            }
        }
    }
}

/// How brightly a triangle is drawn: the more it faces the camera, the brighter (0.35 to 0.95).
pub(crate) fn brightness(view: &View, tri: &[DVec3; 3]) -> f64 {
    let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero();
    let centre = (tri[0] + tri[1] + tri[2]) / 3.0;
    0.35 + 0.6 * normal.dot(view.towards_camera(centre)).abs()
}

/// One view drawn: its pixels, row by row from the top, and its figures.
struct Drawn {
    pixels: Vec<Rgb<u8>>,
    false_pixels: u64,
    covered: u64,
    seen: u64,
}

/// A sphere around both meshes: their bounding boxes' joint centre and the farthest corner.
fn union_sphere(original: &Mesh, occluder: &[PieceTriangle]) -> (DVec3, f64) {
    let points = original
        .triangles_f64()
        .flatten()
        .chain(occluder.iter().flat_map(|t| t.0));
    let (lo, hi) = points.fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
        (lo.min(p), hi.max(p))
    });
    if !lo.is_finite() {
        return (DVec3::ZERO, 1.0);
    }
    ((lo + hi) * 0.5, ((hi - lo).length() * 0.5).max(1e-9))
}

/// The original's nearest depth and shade per pixel, then the occluder's nearest depth and kind
/// over it, composed.
fn draw_view(view: &View, original: &Mesh, occluder: &[PieceTriangle]) -> Drawn {
    let n = view.pixels * view.pixels;
    let (mut depth, mut shade) = (vec![f64::INFINITY; n], vec![0.0f64; n]);
    for tri in original.triangles_f64() {
        let lit = brightness(view, &tri);
        rasterize(view, &tri, |i, d| {
            if d < depth[i] {
                depth[i] = d;
                shade[i] = lit;
            }
        });
    }
    let mut near = vec![f64::INFINITY; n];
    let mut kind = vec![Piece::Solid; n];
    for (tri, piece) in occluder {
        rasterize(view, tri, |i, d| {
            if d < near[i] {
                near[i] = d;
                kind[i] = *piece;
            }
        });
    }
    let tolerance = view.depth_tolerance();
    let mut drawn = Drawn {
        pixels: Vec::with_capacity(n),
        false_pixels: 0,
        covered: 0,
        seen: 0,
    };
    // Pixel rows run bottom-up in the raster; images top-down.
    for row in (0..view.pixels).rev() {
        for i in row * view.pixels..(row + 1) * view.pixels {
            let visible = depth[i].is_finite();
            drawn.seen += u64::from(visible);
            let base = match visible {
                true => [shade[i] * 200.0; 3],
                false => BACKGROUND.0.map(f64::from),
            };
            let rgb = if !near[i].is_finite() {
                base
            } else if !visible || near[i] < depth[i] - tolerance {
                drawn.false_pixels += 1;
                FALSE_PIXEL.0.map(f64::from)
            } else {
                drawn.covered += 1;
                let c = kind[i].colour();
                [0, 1, 2].map(|k| 0.45 * base[k] + 0.55 * c[k])
            };
            drawn.pixels.push(Rgb(rgb.map(|v| v.clamp(0.0, 255.0) as u8)));
        }
    }
    drawn
}

/// Puts view `index`'s pixels (VIEW_PIXELS square, rows from the top) in its cell of a 2×2
/// sheet, named in its corner.
pub(crate) fn place_view(image: &mut RgbImage, index: usize, pixels: &[Rgb<u8>], name: &str) {
    let side = VIEW_PIXELS as u32;
    let (x0, y0) = ((index as u32 % 2) * side, (index as u32 / 2) * side);
    for (p, rgb) in pixels.iter().enumerate() {
        image.put_pixel(x0 + (p % VIEW_PIXELS) as u32, y0 + (p / VIEW_PIXELS) as u32, *rgb);
    }
    text(image, x0 + 6, y0 + 6, 1, name);
}

/// The key to `entries`' colours, right-aligned at `right`; returns where it starts.
pub(crate) fn legend(image: &mut RgbImage, right: u32, y: u32, entries: &[(&str, [f64; 3])]) -> u32 {
    let mut x = right;
    for (name, rgb) in entries.iter().rev() {
        x -= 8 * name.len() as u32 + 20;
        for dy in 0..10 {
            for dx in 0..10 {
                image.put_pixel(x + dx, y + 1 + dy, Rgb(rgb.map(|v| v as u8)));
            }
        }
        text(image, x + 14, y + 2, 1, name);
    }
    x
}

/// Writes `line` at (x, y) in the 8×8 bitmap font, each dot `scale` pixels wide; what does not
/// fit is cut off.
pub(crate) fn text(image: &mut RgbImage, x: u32, y: u32, scale: u32, line: &str) {
    use font8x8::UnicodeFonts;
    for (i, ch) in line.chars().enumerate() {
        let glyph = font8x8::BASIC_FONTS.get(ch).or_else(|| font8x8::BASIC_FONTS.get('?'));
        let Some(glyph) = glyph else { continue };
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits & (1 << col) == 0 {
                    continue;
                }
                for (dx, dy) in (0..scale).flat_map(|dx| (0..scale).map(move |dy| (dx, dy))) {
                    let px = x + (i as u32 * 8 + col) * scale + dx;
                    let py = y + row as u32 * scale + dy;
                    if px < image.width() && py < image.height() {
                        image.put_pixel(px, py, TEXT);
                    }
                }
            }
        }
    }
}

/// The sheet as PNG bytes.
pub fn png(image: &RgbImage) -> Vec<u8> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    image
        .write_to(&mut bytes, image::ImageFormat::Png)
        .expect("a PNG encodes in memory");
    bytes.into_inner()
}
