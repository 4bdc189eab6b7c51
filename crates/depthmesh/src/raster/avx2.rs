//! The rasterizer's hot loops with AVX2, bit for bit as the portable code.
//!
//! Nearly every triangle of a mesh made from depth images covers at most a
//! few pixel centres when seen from another pose, and about half cover none:
//! one at a time, the work per triangle is mostly setup and unpredictable
//! branches. [`draw_small`] sets up eight consecutive triangles side by side
//! (box, orientation, edge functions, the depth plane) and walks their boxes
//! together; only the pixels covered leave the vector registers.
//! [`fill_rows`] walks a larger triangle eight pixels of a row at a time,
//! and [`project`] projects and snaps eight vertices at a time.
//!
//! Each does the portable code's arithmetic operation for operation: edge
//! functions in `i32` only where they are exact, floats in the same order
//! and without fused multiply-adds, so the keys written are bit for bit
//! those of the portable path, which draws whatever is left here.

use super::{Key, Vertices, View, GUARD_BAND, OFF_GRID, SUBPIXEL, SUBPIXEL_BITS};
use crate::camera::Pose;
use glam::Vec3;
use std::arch::x86_64::*;

/// Triangles whose snapped box is narrower and shorter than this (1/256
/// pixel) are drawn here: at most 4 × 4 pixel centres, and every product
/// in their edge functions stays below 2^20.
const MAX_EXTENT: i32 = 4 << SUBPIXEL_BITS;

/// The most pixel centres such a box holds along one axis.
const MAX_CENTRES: i32 = 4;

/// Whether the CPU has AVX2 and there are few enough vertices for this
/// path's `i32` gather offsets (three per vertex).
pub(super) fn usable(vertices: usize) -> bool {
    (1..1 << 28).contains(&vertices) && is_x86_feature_detected!("avx2")
}

/// The three corners of eight triangles, one lane each.
type Corners = [__m256i; 3];

/// Draws those of the triangles `tris` (ids `first..first + 8`) that are
/// small, on the fixed-point grid and not holes into `keys` (the whole
/// image), and returns a bit per triangle left to the caller.
///
/// # Safety
/// The CPU must have AVX2 and the vertex arrays of `v` must be
/// [`usable`] sizes.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn draw_small<K: Key>(
    v: &Vertices,
    tris: &[[u32; 3]; 8],
    first: u32,
    keys: &mut [K],
) -> u32 {
    let zero = _mm256_setzero_si256();
    // Corner indices, clamped into the arrays: a lane with an index out of
    // range is left to the caller, whose indexing reports it.
    let last = _mm256_set1_epi32(v.snapped.len() as i32 - 1);
    // SAFETY: eight triangles are 24 indices.
    let mut idx = deinterleave(tris.as_ptr().cast());
    let mut bad = zero;
    for idx in &mut idx {
        let raw = *idx;
        let clamped = _mm256_min_epu32(raw, last);
        bad = _mm256_or_si256(bad, not(_mm256_cmpeq_epi32(raw, clamped)));
        *idx = clamped;
    }
    let hole = _mm256_and_si256(
        _mm256_cmpeq_epi32(idx[0], idx[1]),
        _mm256_cmpeq_epi32(idx[1], idx[2]),
    );
    bad = _mm256_or_si256(bad, hole);
    // Snapped corners; off the grid is `i32::MIN` in both coordinates.
    let snapped = v.snapped.as_ptr().cast::<i32>();
    let mut x: Corners = [zero; 3];
    let mut y: Corners = [zero; 3];
    for c in 0..3 {
        let at = _mm256_slli_epi32::<1>(idx[c]);
        x[c] = _mm256_i32gather_epi32::<4>(snapped, at);
        y[c] = _mm256_i32gather_epi32::<4>(snapped.add(1), at);
        bad = _mm256_or_si256(bad, _mm256_cmpeq_epi32(x[c], _mm256_set1_epi32(i32::MIN)));
    }
    let (x0, x1) = (min3(x), max3(x));
    let (y0, y1) = (min3(y), max3(y));
    let small = _mm256_and_si256(
        _mm256_cmpgt_epi32(_mm256_set1_epi32(MAX_EXTENT), _mm256_sub_epi32(x1, x0)),
        _mm256_cmpgt_epi32(_mm256_set1_epi32(MAX_EXTENT), _mm256_sub_epi32(y1, y0)),
    );
    let left = _mm256_or_si256(bad, not(small));
    // Pixel centres in the box (ceil(min)..=floor(max)), clipped to the image.
    let round_up = _mm256_set1_epi32((1 << SUBPIXEL_BITS) - 1);
    let centres = |lo: __m256i, hi: __m256i, size: usize| {
        let first = _mm256_srai_epi32::<{ SUBPIXEL_BITS as i32 }>(_mm256_add_epi32(lo, round_up));
        let last = _mm256_srai_epi32::<{ SUBPIXEL_BITS as i32 }>(hi);
        (
            _mm256_max_epi32(first, zero),
            _mm256_min_epi32(last, _mm256_set1_epi32(size as i32 - 1)),
        )
    };
    let (px0, px1) = centres(x0, x1, v.view.width);
    let (py0, py1) = centres(y0, y1, v.view.height);
    let area = _mm256_sub_epi32(
        _mm256_mullo_epi32(_mm256_sub_epi32(x[1], x[0]), _mm256_sub_epi32(y[2], y[0])),
        _mm256_mullo_epi32(_mm256_sub_epi32(x[2], x[0]), _mm256_sub_epi32(y[1], y[0])),
    );
    let drawn = not(_mm256_or_si256(
        _mm256_or_si256(left, _mm256_cmpeq_epi32(area, zero)),
        _mm256_or_si256(_mm256_cmpgt_epi32(px0, px1), _mm256_cmpgt_epi32(py0, py1)),
    ));
    let left = bits(left);
    if bits(drawn) == 0 {
        return left;
    }
    // Edge i from corner i to corner i + 1, walked backwards (negated) in a
    // clockwise triangle; tie rule and steps as in `fill_triangle`.
    let start_x = _mm256_slli_epi32::<{ SUBPIXEL_BITS as i32 }>(px0);
    let start_y = _mm256_slli_epi32::<{ SUBPIXEL_BITS as i32 }>(py0);
    let mut e_row: Corners = [zero; 3];
    let mut step_x: Corners = [zero; 3];
    let mut step_y: Corners = [zero; 3];
    for i in 0..3 {
        let (s, r) = (i, (i + 1) % 3);
        let dx = _mm256_sign_epi32(_mm256_sub_epi32(x[r], x[s]), area);
        let dy = _mm256_sign_epi32(_mm256_sub_epi32(y[r], y[s]), area);
        let owns = _mm256_or_si256(
            _mm256_cmpgt_epi32(zero, dy),
            _mm256_and_si256(_mm256_cmpeq_epi32(dy, zero), _mm256_cmpgt_epi32(dx, zero)),
        );
        e_row[i] = _mm256_add_epi32(
            _mm256_sub_epi32(
                _mm256_mullo_epi32(dx, _mm256_sub_epi32(start_y, y[s])),
                _mm256_mullo_epi32(dy, _mm256_sub_epi32(start_x, x[s])),
            ),
            not(owns), // the bias: 0 on the edges a triangle owns, else −1
        );
        step_x[i] = _mm256_slli_epi32::<{ SUBPIXEL_BITS as i32 }>(_mm256_sub_epi32(zero, dy));
        step_y[i] = _mm256_slli_epi32::<{ SUBPIXEL_BITS as i32 }>(dx);
    }
    let rows = _mm256_sub_epi32(py1, py0);
    let cols = _mm256_sub_epi32(px1, px0);
    let mut plane = None;
    for oy in 0..MAX_CENTRES {
        let in_row = _mm256_and_si256(drawn, _mm256_cmpgt_epi32(rows, _mm256_set1_epi32(oy - 1)));
        if bits(in_row) == 0 {
            break;
        }
        let mut e = e_row;
        for ox in 0..MAX_CENTRES {
            let in_box =
                _mm256_and_si256(in_row, _mm256_cmpgt_epi32(cols, _mm256_set1_epi32(ox - 1)));
            if bits(in_box) == 0 {
                break;
            }
            let inside = _mm256_cmpgt_epi32(
                _mm256_or_si256(_mm256_or_si256(e[0], e[1]), e[2]),
                _mm256_set1_epi32(-1),
            );
            let covered = bits(_mm256_and_si256(in_box, inside));
            if covered != 0 {
                if plane.is_none() {
                    plane = Some(screen_planes(v, &idx));
                }
                let [a, b, k] = plane.expect("fitted above");
                let px = _mm256_add_epi32(px0, _mm256_set1_epi32(ox));
                let py = _mm256_add_epi32(py0, _mm256_set1_epi32(oy));
                let w = _mm256_add_ps(
                    _mm256_mul_ps(a, _mm256_cvtepi32_ps(px)),
                    _mm256_add_ps(_mm256_mul_ps(b, _mm256_cvtepi32_ps(py)), k),
                );
                let at = _mm256_add_epi32(
                    _mm256_mullo_epi32(py, _mm256_set1_epi32(v.view.width as i32)),
                    px,
                );
                let (mut w_lanes, mut at_lanes) = ([0f32; 8], [0i32; 8]);
                _mm256_storeu_ps(w_lanes.as_mut_ptr(), w);
                _mm256_storeu_si256(at_lanes.as_mut_ptr().cast(), at);
                let mut lanes = covered;
                while lanes != 0 {
                    let lane = lanes.trailing_zeros() as usize;
                    lanes &= lanes - 1;
                    let at = at_lanes[lane] as usize;
                    keys[at] = keys[at].max(K::new(w_lanes[lane], first + lane as u32));
                }
            }
            for i in 0..3 {
                e[i] = _mm256_add_epi32(e[i], step_x[i]);
            }
        }
        for i in 0..3 {
            e_row[i] = _mm256_add_epi32(e_row[i], step_y[i]);
        }
    }
    left
}

/// The inverse-depth planes `[a, b, k]` of eight projected triangles, as
/// `screen_plane` fits them.
#[target_feature(enable = "avx2")]
unsafe fn screen_planes(v: &Vertices, idx: &Corners) -> [__m256; 3] {
    let screen = v.screen.as_ptr().cast::<f32>();
    let mut s = [[_mm256_setzero_ps(); 3]; 3];
    for (corner, idx) in s.iter_mut().zip(idx) {
        let at = _mm256_add_epi32(_mm256_slli_epi32::<1>(*idx), *idx);
        for (j, value) in corner.iter_mut().enumerate() {
            *value = _mm256_i32gather_ps::<4>(screen.add(j), at);
        }
    }
    let d = |i: usize, j: usize| _mm256_sub_ps(s[i][j], s[0][j]);
    let (du1, dv1, dw1) = (d(1, 0), d(1, 1), d(1, 2));
    let (du2, dv2, dw2) = (d(2, 0), d(2, 1), d(2, 2));
    let area = _mm256_sub_ps(_mm256_mul_ps(du1, dv2), _mm256_mul_ps(du2, dv1));
    // `area != 0.0`, true for NaN as in Rust.
    let nonzero = _mm256_cmp_ps::<_CMP_NEQ_UQ>(area, _mm256_setzero_ps());
    let a = _mm256_and_ps(
        _mm256_div_ps(
            _mm256_sub_ps(_mm256_mul_ps(dw1, dv2), _mm256_mul_ps(dw2, dv1)),
            area,
        ),
        nonzero,
    );
    let b = _mm256_and_ps(
        _mm256_div_ps(
            _mm256_sub_ps(_mm256_mul_ps(du1, dw2), _mm256_mul_ps(du2, dw1)),
            area,
        ),
        nonzero,
    );
    let k = _mm256_sub_ps(
        _mm256_sub_ps(s[0][2], _mm256_mul_ps(a, s[0][0])),
        _mm256_mul_ps(b, s[0][1]),
    );
    [a, b, k]
}

/// The lanes of a mask as bits.
#[inline]
#[target_feature(enable = "avx2")]
fn bits(mask: __m256i) -> u32 {
    _mm256_movemask_ps(_mm256_castsi256_ps(mask)) as u32
}

/// The complement of a mask.
#[inline]
#[target_feature(enable = "avx2")]
fn not(mask: __m256i) -> __m256i {
    _mm256_xor_si256(mask, _mm256_set1_epi32(-1))
}

/// Lane-wise minimum of three.
#[inline]
#[target_feature(enable = "avx2")]
fn min3(c: Corners) -> __m256i {
    _mm256_min_epi32(_mm256_min_epi32(c[0], c[1]), c[2])
}

/// Lane-wise maximum of three.
#[inline]
#[target_feature(enable = "avx2")]
fn max3(c: Corners) -> __m256i {
    _mm256_max_epi32(_mm256_max_epi32(c[0], c[1]), c[2])
}

/// Whether a triangle whose snapped box is `w × h` (1/256 pixel) can be
/// filled by [`fill_rows`]: its edge functions, over its box and the
/// vectors' overhang past it, stay well within `i32`.
pub(super) fn fits_rows(w: i64, h: i64) -> bool {
    w < 1 << 14 && h < 1 << 14
}

/// A triangle's edge functions at the first pixel centre of its box, and
/// their steps one pixel right and one down.
pub(super) struct Edges {
    pub e: [i32; 3],
    pub step_x: [i32; 3],
    pub step_y: [i32; 3],
}

/// Where [`fill_rows`] draws: depth keys of the image rows from `row0` on,
/// `width` a row.
pub(super) struct Target<'a, K> {
    pub keys: &'a mut [K],
    pub width: usize,
    pub row0: usize,
}

/// The loops of `fill_triangle` eight pixels of a row at a time: draws
/// the pixel centres in rows `rows` and columns `cols` (absolute) inside
/// `edges` with depths from `plane`.
#[target_feature(enable = "avx2")]
pub(super) fn fill_rows<K: Key>(
    edges: &Edges,
    plane: [f32; 3],
    id: u32,
    rows: std::ops::RangeInclusive<usize>,
    cols: std::ops::RangeInclusive<usize>,
    target: Target<K>,
) {
    let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let mut e_row = [_mm256_setzero_si256(); 3];
    for (i, e) in e_row.iter_mut().enumerate() {
        let step = _mm256_mullo_epi32(lane, _mm256_set1_epi32(edges.step_x[i]));
        *e = _mm256_add_epi32(_mm256_set1_epi32(edges.e[i]), step);
    }
    let step_8 = edges.step_x.map(|s| _mm256_set1_epi32(s * 8));
    let step_y = edges.step_y.map(|s| _mm256_set1_epi32(s));
    let [a, b, k] = plane;
    let (px0, px1) = (*cols.start(), *cols.end());
    for py in rows {
        let wy = b * (target.row0 + py) as f32 + k;
        let row = &mut target.keys[py * target.width..][..target.width];
        let mut e = e_row;
        for px in (px0..=px1).step_by(8) {
            let inside = _mm256_cmpgt_epi32(
                _mm256_or_si256(_mm256_or_si256(e[0], e[1]), e[2]),
                _mm256_set1_epi32(-1),
            );
            let in_box = if px1 - px >= 7 {
                0xff
            } else {
                (1 << (px1 - px + 1)) - 1
            };
            let mut covered = bits(inside) & in_box;
            if covered != 0 {
                let u = _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(px as i32), lane));
                let w = _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(a), u), _mm256_set1_ps(wy));
                let mut w_lanes = [0f32; 8];
                // SAFETY: eight floats are stored into eight floats.
                unsafe { _mm256_storeu_ps(w_lanes.as_mut_ptr(), w) };
                while covered != 0 {
                    let l = covered.trailing_zeros() as usize;
                    covered &= covered - 1;
                    let key = &mut row[px + l];
                    *key = (*key).max(K::new(w_lanes[l], id));
                }
            }
            for (e, step) in e.iter_mut().zip(&step_8) {
                *e = _mm256_add_epi32(*e, *step);
            }
        }
        for (e, step) in e_row.iter_mut().zip(&step_y) {
            *e = _mm256_add_epi32(*e, *step);
        }
    }
}

/// `project_vertex` for the vertices `positions` eight at a time, into
/// `screen` and `snapped` (as long); returns how many were projected (the
/// rest, fewer than eight, are the caller's).
#[target_feature(enable = "avx2")]
pub(super) fn project(
    view: &View,
    world_to_camera: &Pose,
    positions: &[Vec3],
    screen: &mut [[f32; 3]],
    snapped: &mut [[i32; 2]],
) -> usize {
    let r = world_to_camera.rotation;
    let t = world_to_camera.translation;
    let axes = [r.x_axis, r.y_axis, r.z_axis];
    let splat = _mm256_set1_ps;
    let groups = positions.chunks_exact(8);
    let done = positions.len() - groups.remainder().len();
    for (g, group) in groups.enumerate() {
        // SAFETY: eight `Vec3`s (three `f32`s each, `repr(C)`) are 24 floats.
        let p = unsafe { deinterleave(group.as_ptr().cast()) }.map(|c| _mm256_castsi256_ps(c));
        // `rotation * p + translation` in glam's order of operations.
        let camera = |row: fn(Vec3) -> f32, t: f32| {
            let sum = _mm256_mul_ps(splat(row(axes[0])), p[0]);
            let sum = _mm256_add_ps(sum, _mm256_mul_ps(splat(row(axes[1])), p[1]));
            let sum = _mm256_add_ps(sum, _mm256_mul_ps(splat(row(axes[2])), p[2]));
            _mm256_add_ps(sum, splat(t))
        };
        let (cx, cy, cz) = (
            camera(|a| a.x, t.x),
            camera(|a| a.y, t.y),
            camera(|a| a.z, t.z),
        );
        let front = _mm256_cmp_ps::<_CMP_GE_OQ>(cz, splat(view.near));
        let inv = _mm256_div_ps(splat(1.0), cz);
        let u = _mm256_add_ps(
            _mm256_mul_ps(_mm256_mul_ps(splat(view.fx), cx), inv),
            splat(view.cx),
        );
        let v = _mm256_add_ps(
            _mm256_mul_ps(_mm256_mul_ps(splat(view.fy), cy), inv),
            splat(view.cy),
        );
        let band = |x: __m256| {
            let abs = _mm256_andnot_ps(splat(-0.0), x);
            _mm256_cmp_ps::<_CMP_LE_OQ>(abs, splat(GUARD_BAND * 2.0))
        };
        let on_grid = _mm256_and_ps(front, _mm256_and_ps(band(u), band(v)));
        // `snap` without its clamp, which the guard band makes a no-op.
        const OFFSET: f32 = (1 << 21) as f32;
        let snap = |x: __m256| {
            let shifted = _mm256_add_ps(_mm256_mul_ps(x, splat(SUBPIXEL)), splat(OFFSET));
            let q = _mm256_sub_epi32(_mm256_cvttps_epi32(shifted), _mm256_set1_epi32(1 << 21));
            _mm256_blendv_epi8(
                _mm256_set1_epi32(OFF_GRID[0]),
                q,
                _mm256_castps_si256(on_grid),
            )
        };
        let lanes = |x: __m256| {
            let mut out = [0f32; 8];
            // SAFETY: eight floats are stored into eight floats.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), x) };
            out
        };
        let q = [snap(u), snap(v)].map(|q| {
            let mut out = [0i32; 8];
            // SAFETY: eight integers are stored into eight integers.
            unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast(), q) };
            out
        });
        let [u, v, w] = [
            _mm256_and_ps(u, front),
            _mm256_and_ps(v, front),
            _mm256_blendv_ps(splat(-1.0), inv, front),
        ]
        .map(lanes);
        let at = 8 * g;
        for l in 0..8 {
            screen[at + l] = [u[l], v[l], w[l]];
            snapped[at + l] = [q[0][l], q[1][l]];
        }
    }
    done
}

/// The three components of eight consecutive triples of 32-bit values
/// from `p`, one vector each: three loads, blends and lane permutations
/// instead of gathers.
///
/// # Safety
/// `p` must point to 24 readable 32-bit values.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn deinterleave(p: *const __m256i) -> [__m256i; 3] {
    let [v0, v1, v2] = [0, 1, 2].map(|i| _mm256_loadu_si256(p.cast::<u32>().add(8 * i).cast()));
    // Lane l of `t` holds a component of triple `[0, 3, 6, 1, 4, 7, 2, 5][l]`
    // for the first, and of those one and two further for the others.
    let first = _mm256_blend_epi32::<0x24>(_mm256_blend_epi32::<0x92>(v0, v1), v2);
    let second = _mm256_blend_epi32::<0x49>(_mm256_blend_epi32::<0x24>(v0, v1), v2);
    let third = _mm256_blend_epi32::<0x92>(_mm256_blend_epi32::<0x49>(v0, v1), v2);
    [
        _mm256_permutevar8x32_epi32(first, _mm256_setr_epi32(0, 3, 6, 1, 4, 7, 2, 5)),
        _mm256_permutevar8x32_epi32(second, _mm256_setr_epi32(1, 4, 7, 2, 5, 0, 3, 6)),
        _mm256_permutevar8x32_epi32(third, _mm256_setr_epi32(2, 5, 0, 3, 6, 1, 4, 7)),
    ]
}
