//! What several stages share and that imports nothing of the pipeline: cameras and their
//! projections ([`camera`]), the rasterizer that draws meshes through them ([`raster`], with its
//! GPU twin), which triangles lie near a point ([`proximity`]), the openings of a mesh narrower
//! than a width, closed ([`openings`]), how many cells of a grid are flagged over a rectangle
//! ([`grid_counts`]), a mesh cut into meshlets that a view keeps or skips whole ([`meshlets`]),
//! and the conversions between pixel or cell indices and floats, the comparisons and the bit
//! counts that their inner loops make.

pub mod camera;
pub mod grid_counts;
pub mod meshlets;
pub mod openings;
pub mod proximity;
pub mod raster;

// On the baseline x86-64 target, usize's conversions to and from f64 take a dozen instructions
// (it has no unsigned ones) and `floor`/`ceil` are library calls; through i32 and u32 they
// take one or two. Pixel and cell indices stay far below 2³¹.

/// `index` as a float.
#[inline(always)]
pub fn index_to_f64(index: usize) -> f64 {
    f64::from(index as u32)
}

/// The greatest index at or below `v`, for v < 2³¹; 0 for negatives and NaN, as `v as usize`.
#[inline(always)]
pub fn floor_index(v: f64) -> usize {
    (v as i32).max(0) as usize
}

/// The index of `n` (at least 1) at or below `v`: the first for negatives and NaN, the last
/// beyond. Truncating a clamped value floors it, where `floor` is a library call.
#[inline(always)]
pub fn clamped_index(v: f64, n: usize) -> usize {
    (v.max(0.0) as usize).min(n - 1)
}

/// The least index at or above `v`, for v < 2³¹; 0 for negatives and NaN.
#[inline(always)]
pub fn ceil_index(v: f64) -> usize {
    let below = (v as i32).max(0);
    below as usize + usize::from(f64::from(below) < v)
}

/// How far writing a point within bounds `lo`..`hi` as f32 (as the occluder GLB does) may move
/// it past the millionth of their size that the stages keep from the surface anyway: an f32 step
/// at the bounds' largest coordinate along each axis (√3 steps in all), less that millionth. 0
/// within a few sizes of the origin; 0.014 for a 2 m mesh 100 km away.
pub fn f32_slack(lo: glam::DVec3, hi: glam::DVec3) -> f64 {
    let moved = 3f64.sqrt() * lo.abs().max(hi.abs()).max_element() * f64::from(f32::EPSILON);
    (moved - 1e-6 * (hi - lo).max_element()).max(0.0)
}

// `f64::min` and `max` also handle a NaN on either side, which costs a compare and a blend
// each; a running bound is never NaN, and one instruction does.

/// The lesser of `a` and `b`, `a` on a tie or where `b` is NaN, as `min` would; `a` is not NaN.
#[inline(always)]
pub fn lesser(a: f64, b: f64) -> f64 {
    if b < a { b } else { a }
}

/// The greater of `a` and `b`, `a` on a tie or where `b` is NaN, as `max` would; `a` is not NaN.
#[inline(always)]
pub fn greater<T: PartialOrd>(a: T, b: T) -> T {
    if b > a { b } else { a }
}

/// `count()`, compiled with the CPU's POPCNT instruction where it has one: the baseline target
/// counts a word's bits in a dozen instructions. For loops of `count_ones` that the caller
/// inlines into it.
#[inline(always)]
pub fn with_popcnt<R>(count: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("popcnt") {
        #[target_feature(enable = "popcnt")]
        fn run<R>(count: impl FnOnce() -> R) -> R {
            count()
        }
        // SAFETY: the CPU has POPCNT.
        return unsafe { run(count) };
    }
    count()
}

/// `work()`, compiled with AVX2's wider vector lanes where the CPU has them: for loops of
/// float operations that the caller inlines into it, which then give the same values to the bit
/// (Rust fuses no multiply with an add).
#[inline(always)]
pub fn with_avx2<R>(work: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        #[target_feature(enable = "avx2")]
        fn run<R>(work: impl FnOnce() -> R) -> R {
            work()
        }
        // SAFETY: the CPU has AVX2.
        return unsafe { run(work) };
    }
    work()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_conversions_agree_with_usize_and_rounding() {
        let values = (-40..40)
            .map(|k| f64::from(k) * 0.37)
            .chain([0.0, -0.0, 1.0, 255.0, 255.5, 1e9, f64::NAN]);
        for v in values {
            assert_eq!(floor_index(v), v as usize, "{v}");
            assert_eq!(ceil_index(v), v.ceil() as usize, "{v}");
        }
        for i in [0, 1, 255, 65_536, (1 << 31) - 1] {
            assert_eq!(index_to_f64(i), i as f64);
        }
    }

    #[test]
    fn f32_slack_is_what_rounding_to_f32_moves_a_corner_past_a_millionth_of_the_size() {
        use glam::DVec3;
        let two_metres = |at: f64| f32_slack(DVec3::splat(at - 1.0), DVec3::splat(at + 1.0));
        assert_eq!(two_metres(0.0), 0.0);
        assert_eq!(two_metres(5.0), 0.0);
        // An f32 step at 100 km is 2⁻⁷, under the step counted; rounding each of three
        // coordinates moves a corner up to √3 steps. Less the 2e-6 the stages keep already.
        assert_eq!(f32::from_bits(1e5f32.to_bits() + 1) - 1e5, 2f32.powi(-7));
        let step = (1e5 + 1.0) * f64::from(f32::EPSILON);
        assert!(step >= 2f64.powi(-7));
        assert!((two_metres(1e5) - (3f64.sqrt() * step - 2e-6)).abs() < 1e-12);
    }
}
