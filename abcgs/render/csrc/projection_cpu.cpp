// Fused EWA projection for the fast CPU backend, forward and hand-written backward.
//
// The math is abcgs/render/projection.py line for line (that file is the specification; the tests
// compare the two): p = R m + t; J from the clamped view direction (1.3x FOV, as gsplat);
// Sigma = Rq S S Rq^T; cov2d = J R Sigma R^T J^T + eps2d I; conic = inverse(cov2d) upper triangle;
// means2d = (fx x/z + cx, fy y/z + cy). Gradients flow to means, quaternions (through the
// normalisation) and scales; the camera is treated as constant.

#include <torch/extension.h>

#include "parallel.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace {

constexpr double kAlphaThreshold = 1.0 / 255.0;
constexpr double kRadiusSigmas = 3.33;

template <typename T>
struct Mat3 {
  T m[3][3];
};

template <typename T>
inline Mat3<T> mul(const Mat3<T>& a, const Mat3<T>& b) {
  Mat3<T> r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r.m[i][j] = a.m[i][0] * b.m[0][j] + a.m[i][1] * b.m[1][j] + a.m[i][2] * b.m[2][j];
  return r;
}

template <typename T>
inline Mat3<T> transpose(const Mat3<T>& a) {
  Mat3<T> r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r.m[i][j] = a.m[j][i];
  return r;
}

// Rotation matrix of the normalised quaternion (w, x, y, z); returns false for a zero quaternion
// (identity used, as in projection.py).
template <typename T>
inline bool quat_rotmat(const T* q, T qn[4], T& norm, Mat3<T>& R) {
  norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const bool ok = norm > T(1e-12);
  if (ok) {
    for (int i = 0; i < 4; ++i) qn[i] = q[i] / norm;
  } else {
    qn[0] = 1;
    qn[1] = qn[2] = qn[3] = 0;
  }
  const T w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  R.m[0][0] = 1 - 2 * (y * y + z * z);
  R.m[0][1] = 2 * (x * y - w * z);
  R.m[0][2] = 2 * (x * z + w * y);
  R.m[1][0] = 2 * (x * y + w * z);
  R.m[1][1] = 1 - 2 * (x * x + z * z);
  R.m[1][2] = 2 * (y * z - w * x);
  R.m[2][0] = 2 * (x * z - w * y);
  R.m[2][1] = 2 * (y * z + w * x);
  R.m[2][2] = 1 - 2 * (x * x + y * y);
  return ok;
}

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

// Everything the forward pass computes for one Gaussian that the backward pass needs again.
template <typename T>
struct Ewa {
  T p[3];                 // camera-space mean
  bool in_depth = false;  // near < z < far
  T xz, yz, cx_clamped, cy_clamped, tx, ty;
  T J00, J02, J11, J12;   // the two non-trivial rows of the projection Jacobian
  T qn[4], qnorm;         // normalised quaternion and the input's norm
  bool q_ok = false;
  Mat3<T> Rq, W;          // rotation of the Gaussian; W = R_cam Rq diag(s), so cov_cam = W W^T
  T A[3], B[3];           // rows of J W; cov2d = [[A.A, A.B], [A.B, B.B]] + eps2d I
  T a = 0, b = 0, c = 0, det = 0;
};

template <typename T>
Ewa<T> ewa(const Camera<T>& cam, const T* m, const T* q, const T* s, double near, double far, double eps2d) {
  Ewa<T> e;
  for (int r = 0; r < 3; ++r) e.p[r] = cam.R.m[r][0] * m[0] + cam.R.m[r][1] * m[1] + cam.R.m[r][2] * m[2] + cam.t[r];
  e.in_depth = e.p[2] > T(near) && e.p[2] < T(far);
  if (!e.in_depth) return e;
  const T z = e.p[2];
  e.xz = e.p[0] / z;
  e.yz = e.p[1] / z;
  e.cx_clamped = std::min(cam.lim_x_pos, std::max(-cam.lim_x_neg, e.xz));
  e.cy_clamped = std::min(cam.lim_y_pos, std::max(-cam.lim_y_neg, e.yz));
  e.tx = z * e.cx_clamped;
  e.ty = z * e.cy_clamped;
  e.J00 = cam.fx / z;
  e.J02 = -cam.fx * e.tx / (z * z);
  e.J11 = cam.fy / z;
  e.J12 = -cam.fy * e.ty / (z * z);
  e.q_ok = quat_rotmat(q, e.qn, e.qnorm, e.Rq);
  Mat3<T> M;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) M.m[r][k] = e.Rq.m[r][k] * s[k];
  e.W = mul(cam.R, M);
  for (int k = 0; k < 3; ++k) {
    e.A[k] = e.J00 * e.W.m[0][k] + e.J02 * e.W.m[2][k];
    e.B[k] = e.J11 * e.W.m[1][k] + e.J12 * e.W.m[2][k];
  }
  e.a = e.A[0] * e.A[0] + e.A[1] * e.A[1] + e.A[2] * e.A[2] + T(eps2d);
  e.b = e.A[0] * e.B[0] + e.A[1] * e.B[1] + e.A[2] * e.B[2];
  e.c = e.B[0] * e.B[0] + e.B[1] * e.B[1] + e.B[2] * e.B[2] + T(eps2d);
  e.det = e.a * e.c - e.b * e.b;
  return e;
}

}  // namespace

// Returns (means2d (N,2), conics (N,3), depths (N), extents (N,2), radii (N,2) int32, visible (N) bool).
std::vector<at::Tensor> project_forward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                        const at::Tensor& opacities, const at::Tensor& viewmat, const at::Tensor& K,
                                        int64_t width, int64_t height, double near, double far, double eps2d) {
  const int64_t n = means.size(0);
  auto opts = means.options();
  at::Tensor means2d = at::zeros({n, 2}, opts), conics = at::zeros({n, 3}, opts), depths = at::empty({n}, opts);
  at::Tensor extents = at::zeros({n, 2}, opts), radii = at::zeros({n, 2}, at::kInt), visible = at::zeros({n}, at::kBool);
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "abcgs_project_forward", [&] {
    using T = scalar_t;
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
    abcgs::parallel_range(n, 4096, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) {
        const Ewa<T> e = ewa(cam, mp + 3 * i, qp + 4 * i, sp + 3 * i, near, far, eps2d);
        de[i] = e.p[2];
        if (!e.in_depth || !(e.det > T(1e-12))) continue;
        const T a = e.a, b = e.b, c = e.c, det = e.det, z = e.p[2];
        co[3 * i] = c / det;
        co[3 * i + 1] = -b / det;
        co[3 * i + 2] = a / det;
        const T u = cam.fx * e.p[0] / z + cam.cx, v = cam.fy * e.p[1] / z + cam.cy;
        m2[2 * i] = u;
        m2[2 * i + 1] = v;
        const T s_max = std::log(std::max(T(1), op[i] / T(kAlphaThreshold)));
        if (!(s_max > 0) || !std::isfinite(u) || !std::isfinite(v)) continue;
        const T ha = std::sqrt(std::max(a, T(0))), hc = std::sqrt(std::max(c, T(0)));
        const T k = std::sqrt(T(2) * s_max);
        const T ex_x = k * ha * T(1.001) + T(1e-3), ex_y = k * hc * T(1.001) + T(1e-3);
        if (!(u + ex_x > 0 && u - ex_x < T(width) && v + ex_y > 0 && v - ex_y < T(height))) continue;
        ex[2 * i] = ex_x;
        ex[2 * i + 1] = ex_y;
        ra[2 * i] = static_cast<int32_t>(std::ceil(T(kRadiusSigmas) * ha));
        ra[2 * i + 1] = static_cast<int32_t>(std::ceil(T(kRadiusSigmas) * hc));
        vi[i] = true;
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
  at::Tensor v_means = at::zeros({n, 3}, opts), v_quats = at::zeros({n, 4}, opts), v_scales = at::zeros({n, 3}, opts);
  at::Tensor vm2 = v_means2d.contiguous(), vco = v_conics.contiguous(), vde = v_depths.contiguous();
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "abcgs_project_backward", [&] {
    using T = scalar_t;
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
    abcgs::parallel_range(n, 4096, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) {
        const Ewa<T> e = ewa(cam, mp + 3 * i, qp + 4 * i, sp + 3 * i, near, far, eps2d);
        const T* s = sp + 3 * i;
        const T* p = e.p;
        T v_p[3] = {0, 0, gde[i]};
        if (e.in_depth) {
          const T z = p[2];
          const T tx = e.tx, ty = e.ty, cx_clamped = e.cx_clamped, cy_clamped = e.cy_clamped;
          const bool x_free = e.xz == cx_clamped, y_free = e.yz == cy_clamped;
          const T J00 = e.J00, J02 = e.J02, J11 = e.J11, J12 = e.J12;
          const T *A = e.A, *B = e.B, *qn = e.qn;
          const T a = e.a, b = e.b, c = e.c, det = e.det, qnorm = e.qnorm;
          const bool q_ok = e.q_ok;
          const Mat3<T>& Rq = e.Rq;
          const Mat3<T>& W = e.W;
          if (det > T(1e-12)) {
            // conic = (c, -b, a) / det
            const T g0 = gco[3 * i], g1 = gco[3 * i + 1], g2 = gco[3 * i + 2];
            const T id2 = T(1) / (det * det);
            // d conic / d (a, b, c), with d det = c da + a dc - 2 b db
            const T v_det = -(g0 * c - g1 * b + g2 * a) * id2;
            const T v_a = g2 / det + v_det * c;
            const T v_c = g0 / det + v_det * a;
            const T v_b = -g1 / det + v_det * (-T(2) * b);
            // a = |A|^2, b = A.B, c = |B|^2 with A = J0 W, B = J1 W (rows of J W)
            T vA[3], vB[3];
            for (int k = 0; k < 3; ++k) {
              vA[k] = T(2) * v_a * A[k] + v_b * B[k];
              vB[k] = T(2) * v_c * B[k] + v_b * A[k];
            }
            // A = J00 W0 + J02 W2 ; B = J11 W1 + J12 W2
            Mat3<T> vW;
            T vJ00 = 0, vJ02 = 0, vJ11 = 0, vJ12 = 0;
            for (int k = 0; k < 3; ++k) {
              vW.m[0][k] = J00 * vA[k];
              vW.m[1][k] = J11 * vB[k];
              vW.m[2][k] = J02 * vA[k] + J12 * vB[k];
              vJ00 += vA[k] * W.m[0][k];
              vJ02 += vA[k] * W.m[2][k];
              vJ11 += vB[k] * W.m[1][k];
              vJ12 += vB[k] * W.m[2][k];
            }
            // J entries -> z, tx, ty
            const T z2 = z * z, z3 = z2 * z;
            T v_z = -cam.fx / z2 * vJ00 - cam.fy / z2 * vJ11 + T(2) * cam.fx * tx / z3 * vJ02 +
                    T(2) * cam.fy * ty / z3 * vJ12;
            const T v_tx = -cam.fx / z2 * vJ02, v_ty = -cam.fy / z2 * vJ12;
            if (x_free) v_p[0] += v_tx; else v_z += cx_clamped * v_tx;
            if (y_free) v_p[1] += v_ty; else v_z += cy_clamped * v_ty;
            // means2d
            const T gu = gm2[2 * i], gv = gm2[2 * i + 1];
            v_p[0] += cam.fx / z * gu;
            v_p[1] += cam.fy / z * gv;
            v_z += -cam.fx * p[0] / z2 * gu - cam.fy * p[1] / z2 * gv;
            v_p[2] += v_z;
            // W = Rcam M -> vM = Rcam^T vW ; M = Rq diag(s)
            const Mat3<T> vM = mul(transpose(cam.R), vW);
            T vR[3][3];
            for (int r = 0; r < 3; ++r)
              for (int cc = 0; cc < 3; ++cc) vR[r][cc] = vM.m[r][cc] * s[cc];
            for (int cc = 0; cc < 3; ++cc)
              os[3 * i + cc] = vM.m[0][cc] * Rq.m[0][cc] + vM.m[1][cc] * Rq.m[1][cc] + vM.m[2][cc] * Rq.m[2][cc];
            if (q_ok) {
              const T w = qn[0], x = qn[1], y = qn[2], zq = qn[3];
              T vq[4];
              vq[0] = 2 * (x * (vR[2][1] - vR[1][2]) + y * (vR[0][2] - vR[2][0]) + zq * (vR[1][0] - vR[0][1]));
              vq[1] = 2 * (-2 * x * (vR[1][1] + vR[2][2]) + y * (vR[1][0] + vR[0][1]) + zq * (vR[2][0] + vR[0][2]) +
                           w * (vR[2][1] - vR[1][2]));
              vq[2] = 2 * (x * (vR[1][0] + vR[0][1]) - 2 * y * (vR[0][0] + vR[2][2]) + zq * (vR[2][1] + vR[1][2]) +
                           w * (vR[0][2] - vR[2][0]));
              vq[3] = 2 * (x * (vR[2][0] + vR[0][2]) + y * (vR[2][1] + vR[1][2]) - 2 * zq * (vR[0][0] + vR[1][1]) +
                           w * (vR[1][0] - vR[0][1]));
              const T dot = vq[0] * qn[0] + vq[1] * qn[1] + vq[2] * qn[2] + vq[3] * qn[3];
              for (int k = 0; k < 4; ++k) oq[4 * i + k] = (vq[k] - dot * qn[k]) / qnorm;
            }
          }
        }
        for (int cc = 0; cc < 3; ++cc)
          om[3 * i + cc] = cam.R.m[0][cc] * v_p[0] + cam.R.m[1][cc] * v_p[1] + cam.R.m[2][cc] * v_p[2];
      }
    });
  });
  return {v_means, v_quats, v_scales};
}
