// Fused EWA projection for the fast CPU backend, forward and hand-written backward.
//
// The math is abcgs/render/projection.py line for line (that file is the specification; the tests
// compare the two): p = R m + t; J from the clamped view direction (1.3x FOV, as gsplat);
// Sigma = Rq S S Rq^T; cov2d = J R Sigma R^T J^T + eps2d I; conic = inverse(cov2d) upper triangle;
// means2d = (fx x/z + cx, fy y/z + cy). Gradients flow to means, quaternions (through the
// normalisation) and scales; the camera is treated as constant.
//
// Gaussians are processed a vector of them at a time (GCC/Clang vector extensions at the target's native width:
// 16 floats or 8 doubles with AVX-512, 8/4 with AVX2, 4/2 with SSE or NEON), each lane one Gaussian: the inputs
// are gathered into one vector per component, every formula runs on whole vectors, and the per-Gaussian branches of
// the math (behind the camera, a degenerate covariance, a zero quaternion, a clamped view direction, off-screen)
// become lane masks that select what is written. Each lane evaluates exactly the scalar operations in the order of
// the formulas below (no contraction into FMAs: -ffp-contract=off), so the result of a Gaussian does not depend on
// its lane, its chunk or the thread count. The one-Gaussian code this replaced (5.6 ms forward, 8.3 ms backward
// for fern's 92k Gaussians on two Zen 4 cores, now 0.8 and 0.9 ms: eval/bench_render_scene.py) gave the same
// bits in float32.

#include "torch_api.h"

#include "parallel.h"
#include "thresholds.h"
#include "vec_width.h"

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

constexpr double kRadiusSigmas = 3.33;

// V: a vector of T, M: the integer vector a comparison of two V gives (all ones where true).
template <typename T>
struct Lanes;
template <>
struct Lanes<float> {
  typedef float V __attribute__((vector_size(ABCGS_VEC_BYTES)));
  typedef int32_t M __attribute__((vector_size(ABCGS_VEC_BYTES)));
};
template <>
struct Lanes<double> {
  typedef double V __attribute__((vector_size(ABCGS_VEC_BYTES)));
  typedef int64_t M __attribute__((vector_size(ABCGS_VEC_BYTES)));
};
typedef Lanes<float>::V f32x;
typedef Lanes<double>::V f64x;

template <typename V>
constexpr int64_t lanes_of() {
  return static_cast<int64_t>(sizeof(V) / sizeof(V{}[0]));
}

template <typename V, typename T>
inline V splat(T x) {
  V v;
  for (int64_t l = 0; l < lanes_of<V>(); ++l) v[l] = x;
  return v;
}

inline f32x vsqrt(f32x x) {
#if ABCGS_VEC_BYTES == 64
  return (f32x)_mm512_sqrt_ps((__m512)x);
#elif ABCGS_VEC_BYTES == 32
  return (f32x)_mm256_sqrt_ps((__m256)x);
#elif defined(__SSE2__)
  return (f32x)_mm_sqrt_ps((__m128)x);
#else
  for (int64_t l = 0; l < lanes_of<f32x>(); ++l) x[l] = std::sqrt(x[l]);
  return x;
#endif
}

inline f64x vsqrt(f64x x) {
#if ABCGS_VEC_BYTES == 64
  return (f64x)_mm512_sqrt_pd((__m512d)x);
#elif ABCGS_VEC_BYTES == 32
  return (f64x)_mm256_sqrt_pd((__m256d)x);
#elif defined(__SSE2__)
  return (f64x)_mm_sqrt_pd((__m128d)x);
#else
  for (int64_t l = 0; l < lanes_of<f64x>(); ++l) x[l] = std::sqrt(x[l]);
  return x;
#endif
}

// std::min(a, b) and std::max(a, b) lane by lane, NaNs included: (b < a) ? b : a and (a < b) ? b : a.
template <typename V>
inline V vmin(V a, V b) {
  return b < a ? b : a;
}
template <typename V>
inline V vmax(V a, V b) {
  return a < b ? b : a;
}

template <typename T>
struct Mat3 {
  T m[3][3];
};

template <typename T>
struct Camera {
  Mat3<T> R;
  T t[3];
  T fx, fy, cx, cy;
  T lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg;
};

template <typename T>
Camera<T> make_camera(const at::Tensor& viewmat, const at::Tensor& K, int64_t width, int64_t height) {
  auto vm = viewmat.to(at::kDouble).contiguous();
  auto kk = K.to(at::kDouble).contiguous();
  const double* v = vm.data_ptr<double>();
  const double* k = kk.data_ptr<double>();
  Camera<T> c;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) c.R.m[i][j] = T(v[4 * i + j]);
    c.t[i] = T(v[4 * i + 3]);
  }
  c.fx = T(k[0]);
  c.fy = T(k[4]);
  c.cx = T(k[2]);
  c.cy = T(k[5]);
  const T tan_fovx = T(0.5) * T(width) / c.fx, tan_fovy = T(0.5) * T(height) / c.fy;
  c.lim_x_pos = (T(width) - c.cx) / c.fx + T(0.3) * tan_fovx;
  c.lim_x_neg = c.cx / c.fx + T(0.3) * tan_fovx;
  c.lim_y_pos = (T(height) - c.cy) / c.fy + T(0.3) * tan_fovy;
  c.lim_y_neg = c.cy / c.fy + T(0.3) * tan_fovy;
  return c;
}

// Everything the forward pass computes for a vector of Gaussians that the backward pass needs again.
template <typename T>
struct Ewa {
  using V = typename Lanes<T>::V;
  using M = typename Lanes<T>::M;
  V p[3];                 // camera-space mean
  M in_depth;             // near < z < far
  V xz, yz, cx_clamped, cy_clamped, tx, ty;
  V J00, J02, J11, J12;   // the two non-trivial rows of the projection Jacobian
  V qn[4], qnorm;         // normalised quaternion (identity where the input is zero) and the input's norm
  M q_ok;                 // the quaternion's norm is above 1e-12
  V Rq[3][3], W[3][3];    // rotation of the Gaussian; W = R_cam Rq diag(s), so cov_cam = W W^T
  V A[3], B[3];           // rows of J W; cov2d = [[A.A, A.B], [A.B, B.B]] + eps2d I
  V a, b, c, det;
};

// Lanes behind the camera or with a zero quaternion compute on (values they discard).
template <typename T>
Ewa<T> ewa(const Camera<T>& cam, const typename Lanes<T>::V m[3], const typename Lanes<T>::V q[4],
           const typename Lanes<T>::V s[3], double near, double far, double eps2d) {
  using V = typename Lanes<T>::V;
  Ewa<T> e;
  for (int r = 0; r < 3; ++r) e.p[r] = cam.R.m[r][0] * m[0] + cam.R.m[r][1] * m[1] + cam.R.m[r][2] * m[2] + cam.t[r];
  e.in_depth = (e.p[2] > T(near)) & (e.p[2] < T(far));
  const V z = e.p[2];
  e.xz = e.p[0] / z;
  e.yz = e.p[1] / z;
  e.cx_clamped = vmin(splat<V>(cam.lim_x_pos), vmax(splat<V>(-cam.lim_x_neg), e.xz));
  e.cy_clamped = vmin(splat<V>(cam.lim_y_pos), vmax(splat<V>(-cam.lim_y_neg), e.yz));
  e.tx = z * e.cx_clamped;
  e.ty = z * e.cy_clamped;
  e.J00 = cam.fx / z;
  e.J02 = -cam.fx * e.tx / (z * z);
  e.J11 = cam.fy / z;
  e.J12 = -cam.fy * e.ty / (z * z);
  // rotation matrix of the normalised quaternion (w, x, y, z); the identity for a zero quaternion (projection.py)
  e.qnorm = vsqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  e.q_ok = e.qnorm > T(1e-12);
  for (int i = 0; i < 4; ++i) e.qn[i] = e.q_ok ? q[i] / e.qnorm : splat<V>(T(i == 0 ? 1 : 0));
  const V w = e.qn[0], x = e.qn[1], y = e.qn[2], zq = e.qn[3];
  e.Rq[0][0] = T(1) - T(2) * (y * y + zq * zq);
  e.Rq[0][1] = T(2) * (x * y - w * zq);
  e.Rq[0][2] = T(2) * (x * zq + w * y);
  e.Rq[1][0] = T(2) * (x * y + w * zq);
  e.Rq[1][1] = T(1) - T(2) * (x * x + zq * zq);
  e.Rq[1][2] = T(2) * (y * zq - w * x);
  e.Rq[2][0] = T(2) * (x * zq - w * y);
  e.Rq[2][1] = T(2) * (y * zq + w * x);
  e.Rq[2][2] = T(1) - T(2) * (x * x + y * y);
  V Ms[3][3];  // Rq diag(s)
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) Ms[r][k] = e.Rq[r][k] * s[k];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      e.W[i][j] = cam.R.m[i][0] * Ms[0][j] + cam.R.m[i][1] * Ms[1][j] + cam.R.m[i][2] * Ms[2][j];
  for (int k = 0; k < 3; ++k) {
    e.A[k] = e.J00 * e.W[0][k] + e.J02 * e.W[2][k];
    e.B[k] = e.J11 * e.W[1][k] + e.J12 * e.W[2][k];
  }
  e.a = e.A[0] * e.A[0] + e.A[1] * e.A[1] + e.A[2] * e.A[2] + T(eps2d);
  e.b = e.A[0] * e.B[0] + e.A[1] * e.B[1] + e.A[2] * e.B[2];
  e.c = e.B[0] * e.B[0] + e.B[1] * e.B[1] + e.B[2] * e.B[2] + T(eps2d);
  e.det = e.a * e.c - e.b * e.b;
  return e;
}

// Lane l of the chunk starting at Gaussian i0 reads Gaussian min(i0 + l, n - 1) (the last chunk's spare lanes repeat
// the last Gaussian and are never written back).
template <typename V, int K, typename T>
inline void gather(const T* src, int64_t i0, int64_t n, V out[K]) {
  for (int64_t l = 0; l < lanes_of<V>(); ++l) {
    const int64_t i = std::min(i0 + l, n - 1);
    for (int k = 0; k < K; ++k) out[k][l] = src[K * i + k];
  }
}

// As gather, for the rows rows[r0 + l] (the last chunk's spare lanes repeat the last row).
template <typename V, int K, typename T>
inline void gather_rows(const T* src, const int64_t* rows, int64_t r0, int64_t nr, V out[K]) {
  for (int64_t l = 0; l < lanes_of<V>(); ++l) {
    const int64_t i = rows[std::min(r0 + l, nr - 1)];
    for (int k = 0; k < K; ++k) out[k][l] = src[K * i + k];
  }
}

// The Gaussians, in index order, with a nonzero means2d (N, 2), conic (N, 3) or depth (N) gradient (NaN counts as
// nonzero).
template <typename T>
std::vector<int64_t> rows_with_gradient(const T* gm2, const T* gco, const T* gde, int64_t n) {
  auto has = [&](int64_t i) {
    return !(gm2[2 * i] == T(0) && gm2[2 * i + 1] == T(0) && gco[3 * i] == T(0) && gco[3 * i + 1] == T(0) &&
             gco[3 * i + 2] == T(0) && gde[i] == T(0));
  };
  std::vector<int64_t> rows;
  abcgs::parallel_compact(n, has, [&](int64_t m) { rows.resize(m); }, [&](int64_t i, int64_t j) { rows[j] = i; });
  return rows;
}

}  // namespace

// Returns (means2d (N,2), conics (N,3), depths (N), extents (N,2), radii (N,2) int32, visible (N) bool).
std::vector<at::Tensor> project_forward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                        const at::Tensor& opacities, const at::Tensor& viewmat, const at::Tensor& K,
                                        int64_t width, int64_t height, double near, double far, double eps2d) {
  const int64_t n = means.size(0);
  auto opts = means.options();
  // every element is written below (zeros where a Gaussian is culled)
  at::Tensor means2d = at::empty({n, 2}, opts), conics = at::empty({n, 3}, opts), depths = at::empty({n}, opts);
  at::Tensor extents = at::empty({n, 2}, opts), radii = at::empty({n, 2}, opts.dtype(at::kInt)),
             visible = at::empty({n}, opts.dtype(at::kBool));
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "abcgs_project_forward", [&] {
    using T = scalar_t;
    using V = typename Lanes<T>::V;
    using M = typename Lanes<T>::M;
    constexpr int64_t L = lanes_of<V>();
    const Camera<T> cam = make_camera<T>(viewmat, K, width, height);
    const T* mp = means.data_ptr<T>();
    const T* qp = quats.data_ptr<T>();
    const T* sp = scales.data_ptr<T>();
    const T* op = opacities.data_ptr<T>();
    T* m2 = means2d.data_ptr<T>();
    T* co = conics.data_ptr<T>();
    T* de = depths.data_ptr<T>();
    T* ex = extents.data_ptr<T>();
    int32_t* ra = radii.data_ptr<int32_t>();
    bool* vi = visible.data_ptr<bool>();
    const V zero = splat<V>(T(0));
    abcgs::parallel_range((n + L - 1) / L, 256, [&](int64_t c0, int64_t c1) {
      for (int64_t chunk = c0; chunk < c1; ++chunk) {
        const int64_t i0 = chunk * L, live = std::min(L, n - i0);
        V m[3], q[4], s[3], o[1];
        gather<V, 3>(mp, i0, n, m);
        gather<V, 4>(qp, i0, n, q);
        gather<V, 3>(sp, i0, n, s);
        gather<V, 1>(op, i0, n, o);
        const Ewa<T> e = ewa(cam, m, q, s, near, far, eps2d);
        const V a = e.a, b = e.b, c = e.c, det = e.det, z = e.p[2];
        const M projected = e.in_depth & (det > T(1e-12));
        const V co0 = c / det, co1 = -b / det, co2 = a / det;
        const V u = cam.fx * e.p[0] / z + cam.cx, v = cam.fy * e.p[1] / z + cam.cy;
        V s_max;
        for (int64_t l = 0; l < L; ++l) s_max[l] = std::log(std::max(T(1), o[0][l] / T(kAlphaThreshold)));
        const V ha = vsqrt(vmax(a, zero)), hc = vsqrt(vmax(c, zero));
        const V k = vsqrt(T(2) * s_max);
        const V ex_x = k * ha * T(1.001) + T(1e-3), ex_y = k * hc * T(1.001) + T(1e-3);
        // finite: x - x is 0 (inf - inf and NaN - NaN are NaN)
        const M splat_ok = projected & (s_max > T(0)) & ((u - u) == zero) & ((v - v) == zero);
        const M on_screen = splat_ok & (u + ex_x > T(0)) & (u - ex_x < T(width)) & (v + ex_y > T(0)) &
                            (v - ex_y < T(height));
        for (int64_t l = 0; l < live; ++l) {
          const int64_t i = i0 + l;
          de[i] = z[l];
          const bool pr = projected[l] != 0, vis = on_screen[l] != 0;
          co[3 * i] = pr ? co0[l] : T(0);
          co[3 * i + 1] = pr ? co1[l] : T(0);
          co[3 * i + 2] = pr ? co2[l] : T(0);
          m2[2 * i] = pr ? u[l] : T(0);
          m2[2 * i + 1] = pr ? v[l] : T(0);
          ex[2 * i] = vis ? ex_x[l] : T(0);
          ex[2 * i + 1] = vis ? ex_y[l] : T(0);
          ra[2 * i] = vis ? static_cast<int32_t>(std::ceil(T(kRadiusSigmas) * ha[l])) : 0;
          ra[2 * i + 1] = vis ? static_cast<int32_t>(std::ceil(T(kRadiusSigmas) * hc[l])) : 0;
          vi[i] = vis;
        }
      }
    });
  });
  return {means2d, conics, depths, extents, radii, visible};
}

// Returns (v_means (N,3), v_quats (N,4), v_scales (N,3)).
std::vector<at::Tensor> project_backward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                         const at::Tensor& viewmat, const at::Tensor& K, int64_t width, int64_t height,
                                         double near, double far, double eps2d, const at::Tensor& v_means2d,
                                         const at::Tensor& v_conics, const at::Tensor& v_depths) {
  const int64_t n = means.size(0);
  auto opts = means.options();
  // zeros where no gradient comes in: a Gaussian whose means2d, conic and depth gradients are all 0 (out of view, or
  // blending no pixel: most of a large scene's) has parameter gradients 0, and only the others are computed
  at::Tensor v_means = at::zeros({n, 3}, opts), v_quats = at::zeros({n, 4}, opts), v_scales = at::zeros({n, 3}, opts);
  at::Tensor vm2 = v_means2d.contiguous(), vco = v_conics.contiguous(), vde = v_depths.contiguous();
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "abcgs_project_backward", [&] {
    using T = scalar_t;
    using V = typename Lanes<T>::V;
    using M = typename Lanes<T>::M;
    constexpr int64_t L = lanes_of<V>();
    const Camera<T> cam = make_camera<T>(viewmat, K, width, height);
    const T* mp = means.data_ptr<T>();
    const T* qp = quats.data_ptr<T>();
    const T* sp = scales.data_ptr<T>();
    const T* gm2 = vm2.data_ptr<T>();
    const T* gco = vco.data_ptr<T>();
    const T* gde = vde.data_ptr<T>();
    T* om = v_means.data_ptr<T>();
    T* oq = v_quats.data_ptr<T>();
    T* os = v_scales.data_ptr<T>();
    const V zero = splat<V>(T(0));
    const std::vector<int64_t> rows = rows_with_gradient(gm2, gco, gde, n);
    const int64_t nr = static_cast<int64_t>(rows.size());
    const int64_t* ri = rows.data();
    abcgs::parallel_range((nr + L - 1) / L, 256, [&](int64_t c0, int64_t c1) {
      for (int64_t chunk = c0; chunk < c1; ++chunk) {
        const int64_t i0 = chunk * L, live = std::min(L, nr - i0);
        V m[3], q[4], s[3], gconic[3], gmean[2], gdepth[1];
        gather_rows<V, 3>(mp, ri, i0, nr, m);
        gather_rows<V, 4>(qp, ri, i0, nr, q);
        gather_rows<V, 3>(sp, ri, i0, nr, s);
        gather_rows<V, 3>(gco, ri, i0, nr, gconic);
        gather_rows<V, 2>(gm2, ri, i0, nr, gmean);
        gather_rows<V, 1>(gde, ri, i0, nr, gdepth);
        const Ewa<T> e = ewa(cam, m, q, s, near, far, eps2d);
        const V* p = e.p;
        const V z = p[2];
        const V tx = e.tx, ty = e.ty, cx_clamped = e.cx_clamped, cy_clamped = e.cy_clamped;
        const M x_free = e.xz == cx_clamped, y_free = e.yz == cy_clamped;
        const V J00 = e.J00, J02 = e.J02, J11 = e.J11, J12 = e.J12;
        const V a = e.a, b = e.b, c = e.c, det = e.det;
        // lanes in front of the camera with an invertible cov2d; the others pass only the depth gradient to the mean
        const M projected = e.in_depth & (det > T(1e-12));
        // conic = (c, -b, a) / det
        const V g0 = gconic[0], g1 = gconic[1], g2 = gconic[2];
        const V id2 = T(1) / (det * det);
        // d conic / d (a, b, c), with d det = c da + a dc - 2 b db
        const V v_det = -(g0 * c - g1 * b + g2 * a) * id2;
        const V v_a = g2 / det + v_det * c;
        const V v_c = g0 / det + v_det * a;
        const V v_b = -g1 / det + v_det * (-T(2) * b);
        // a = |A|^2, b = A.B, c = |B|^2 with A = J0 W, B = J1 W (rows of J W)
        V vA[3], vB[3];
        for (int k = 0; k < 3; ++k) {
          vA[k] = T(2) * v_a * e.A[k] + v_b * e.B[k];
          vB[k] = T(2) * v_c * e.B[k] + v_b * e.A[k];
        }
        // A = J00 W0 + J02 W2 ; B = J11 W1 + J12 W2
        V vW[3][3];
        V vJ00 = zero, vJ02 = zero, vJ11 = zero, vJ12 = zero;
        for (int k = 0; k < 3; ++k) {
          vW[0][k] = J00 * vA[k];
          vW[1][k] = J11 * vB[k];
          vW[2][k] = J02 * vA[k] + J12 * vB[k];
          vJ00 += vA[k] * e.W[0][k];
          vJ02 += vA[k] * e.W[2][k];
          vJ11 += vB[k] * e.W[1][k];
          vJ12 += vB[k] * e.W[2][k];
        }
        // J entries -> z, tx, ty
        const V z2 = z * z, z3 = z2 * z;
        V v_z = -cam.fx / z2 * vJ00 - cam.fy / z2 * vJ11 + T(2) * cam.fx * tx / z3 * vJ02 +
                T(2) * cam.fy * ty / z3 * vJ12;
        const V v_tx = -cam.fx / z2 * vJ02, v_ty = -cam.fy / z2 * vJ12;
        V v_p0 = x_free ? zero + v_tx : zero, v_p1 = y_free ? zero + v_ty : zero;
        v_z = x_free ? v_z : v_z + cx_clamped * v_tx;
        v_z = y_free ? v_z : v_z + cy_clamped * v_ty;
        // means2d
        const V gu = gmean[0], gv = gmean[1];
        v_p0 += cam.fx / z * gu;
        v_p1 += cam.fy / z * gv;
        v_z += -cam.fx * p[0] / z2 * gu - cam.fy * p[1] / z2 * gv;
        const V v_p2 = gdepth[0] + v_z;
        // W = Rcam M -> vM = Rcam^T vW ; M = Rq diag(s)
        V vM[3][3], vR[3][3], v_s[3];
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 3; ++j)
            vM[i][j] = cam.R.m[0][i] * vW[0][j] + cam.R.m[1][i] * vW[1][j] + cam.R.m[2][i] * vW[2][j];
        for (int r = 0; r < 3; ++r)
          for (int cc = 0; cc < 3; ++cc) vR[r][cc] = vM[r][cc] * s[cc];
        for (int cc = 0; cc < 3; ++cc)
          v_s[cc] = vM[0][cc] * e.Rq[0][cc] + vM[1][cc] * e.Rq[1][cc] + vM[2][cc] * e.Rq[2][cc];
        const V *qn = e.qn;
        const V w = qn[0], x = qn[1], y = qn[2], zq = qn[3];
        V vq[4];
        vq[0] = T(2) * (x * (vR[2][1] - vR[1][2]) + y * (vR[0][2] - vR[2][0]) + zq * (vR[1][0] - vR[0][1]));
        vq[1] = T(2) * (T(-2) * x * (vR[1][1] + vR[2][2]) + y * (vR[1][0] + vR[0][1]) + zq * (vR[2][0] + vR[0][2]) +
                        w * (vR[2][1] - vR[1][2]));
        vq[2] = T(2) * (x * (vR[1][0] + vR[0][1]) - T(2) * y * (vR[0][0] + vR[2][2]) + zq * (vR[2][1] + vR[1][2]) +
                        w * (vR[0][2] - vR[2][0]));
        vq[3] = T(2) * (x * (vR[2][0] + vR[0][2]) + y * (vR[2][1] + vR[1][2]) - T(2) * zq * (vR[0][0] + vR[1][1]) +
                        w * (vR[1][0] - vR[0][1]));
        const V dot = vq[0] * qn[0] + vq[1] * qn[1] + vq[2] * qn[2] + vq[3] * qn[3];
        V v_q[4];
        for (int k = 0; k < 4; ++k) v_q[k] = (vq[k] - dot * qn[k]) / e.qnorm;
        // the mean's gradient: (v_tx/v_ty/means2d/depth terms, depth) where projected, (0, 0, depth) elsewhere
        const V vp0 = projected ? v_p0 : zero, vp1 = projected ? v_p1 : zero, vp2 = projected ? v_p2 : gdepth[0];
        const M rotated = projected & e.q_ok;
        V v_m[3];
        for (int cc = 0; cc < 3; ++cc) v_m[cc] = cam.R.m[0][cc] * vp0 + cam.R.m[1][cc] * vp1 + cam.R.m[2][cc] * vp2;
        for (int64_t l = 0; l < live; ++l) {
          const int64_t i = ri[i0 + l];
          const bool pr = projected[l] != 0, rot = rotated[l] != 0;
          for (int cc = 0; cc < 3; ++cc) om[3 * i + cc] = v_m[cc][l];
          for (int cc = 0; cc < 3; ++cc) os[3 * i + cc] = pr ? v_s[cc][l] : T(0);
          for (int k = 0; k < 4; ++k) oq[4 * i + k] = rot ? v_q[k][l] : T(0);
        }
      }
    });
  });
  return {v_means, v_quats, v_scales};
}
