// View-dependent colours from spherical harmonics, fused (CPU): colour = max(SH(dir) . coeffs + 0.5, 0) with
// dir = normalise(mean - camera), the 3DGS convention of abcgs/render/sh.py (its torch code is the reference).
//
// Only the rows a mask selects (the Gaussians the projection kept) are evaluated; the others get colour 0 and
// gradient 0. The coefficients come as two blocks, the DC band (N, 1, 3) and the higher bands (N, K - 1, 3),
// as a GaussianModel stores them, so that no (N, K, 3) concatenation is built per render; the backward pass
// writes only the gradients asked for (the higher bands' and the means' are skipped when they are frozen).
// Each row is computed by one worker, so results do not depend on the thread count (parallel.h).

#include "torch_api.h"

#include <cmath>
#include <cstdint>

#include "parallel.h"

namespace {

constexpr double kC0 = 0.28209479177387814, kC1 = 0.4886025119029199;
constexpr double kC2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                           0.5462742152960396};
constexpr double kC3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                           -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

// The 16 basis values at unit direction (x, y, z); bases past (degree + 1)^2 are not written.
template <typename T>
inline void sh_basis(int64_t degree, T x, T y, T z, T* b) {
  b[0] = T(kC0);
  if (degree < 1) return;
  b[1] = -T(kC1) * y;
  b[2] = T(kC1) * z;
  b[3] = -T(kC1) * x;
  if (degree < 2) return;
  const T xx = x * x, yy = y * y, zz = z * z;
  b[4] = T(kC2[0]) * x * y;
  b[5] = T(kC2[1]) * y * z;
  b[6] = T(kC2[2]) * (T(2) * zz - xx - yy);
  b[7] = T(kC2[3]) * x * z;
  b[8] = T(kC2[4]) * (xx - yy);
  if (degree < 3) return;
  b[9] = T(kC3[0]) * y * (T(3) * xx - yy);
  b[10] = T(kC3[1]) * x * y * z;
  b[11] = T(kC3[2]) * y * (T(4) * zz - xx - yy);
  b[12] = T(kC3[3]) * z * (T(2) * zz - T(3) * xx - T(3) * yy);
  b[13] = T(kC3[4]) * x * (T(4) * zz - xx - yy);
  b[14] = T(kC3[5]) * z * (xx - yy);
  b[15] = T(kC3[6]) * x * (xx - T(3) * yy);
}

// d(basis . w)/d(x, y, z) for basis weights w (bases 1 .. (degree + 1)^2 - 1; the DC basis is constant).
template <typename T>
inline void sh_basis_grad(int64_t degree, T x, T y, T z, const T* w, T g[3]) {
  g[0] = g[1] = g[2] = T(0);
  if (degree < 1) return;
  g[0] += -T(kC1) * w[3];
  g[1] += -T(kC1) * w[1];
  g[2] += T(kC1) * w[2];
  if (degree < 2) return;
  const T xx = x * x, yy = y * y, zz = z * z;
  g[0] += T(kC2[0]) * y * w[4] - T(2 * kC2[2]) * x * w[6] + T(kC2[3]) * z * w[7] + T(2 * kC2[4]) * x * w[8];
  g[1] += T(kC2[0]) * x * w[4] + T(kC2[1]) * z * w[5] - T(2 * kC2[2]) * y * w[6] - T(2 * kC2[4]) * y * w[8];
  g[2] += T(kC2[1]) * y * w[5] + T(4 * kC2[2]) * z * w[6] + T(kC2[3]) * x * w[7];
  if (degree < 3) return;
  g[0] += T(kC3[0]) * T(6) * x * y * w[9] + T(kC3[1]) * y * z * w[10] - T(kC3[2]) * T(2) * x * y * w[11] -
          T(kC3[3]) * T(6) * x * z * w[12] + T(kC3[4]) * (T(4) * zz - T(3) * xx - yy) * w[13] +
          T(kC3[5]) * T(2) * x * z * w[14] + T(kC3[6]) * T(3) * (xx - yy) * w[15];
  g[1] += T(kC3[0]) * T(3) * (xx - yy) * w[9] + T(kC3[1]) * x * z * w[10] +
          T(kC3[2]) * (T(4) * zz - xx - T(3) * yy) * w[11] - T(kC3[3]) * T(6) * y * z * w[12] -
          T(kC3[4]) * T(2) * x * y * w[13] - T(kC3[5]) * T(2) * y * z * w[14] - T(kC3[6]) * T(6) * x * y * w[15];
  g[2] += T(kC3[1]) * x * y * w[10] + T(kC3[2]) * T(8) * y * z * w[11] +
          T(kC3[3]) * (T(6) * zz - T(3) * xx - T(3) * yy) * w[12] + T(kC3[4]) * T(8) * x * z * w[13] +
          T(kC3[5]) * (xx - yy) * w[14];
}

// Unit direction from the camera to a mean and the length before normalising (clamped as in sh.py).
template <typename T>
inline T unit_dir(const T* mean, const T* cam, T d[3]) {
  d[0] = mean[0] - cam[0];
  d[1] = mean[1] - cam[1];
  d[2] = mean[2] - cam[2];
  const T len = std::max(std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), T(1e-12));
  d[0] /= len;
  d[1] /= len;
  d[2] /= len;
  return len;
}

// Coefficient k, channel c of row g: the DC block for k = 0, the higher block after.
template <typename T>
inline T coeff(const T* sh0, const T* shN, int64_t kn, int64_t g, int64_t k, int64_t c) {
  return k == 0 ? sh0[3 * g + c] : shN[(g * kn + (k - 1)) * 3 + c];
}

void check_sh_inputs(const at::Tensor& sh0, const at::Tensor& shN, const at::Tensor& means, const at::Tensor& campos,
                     const at::Tensor& mask, int64_t degree) {
  for (const auto* t : {&sh0, &shN, &means, &campos, &mask}) {
    TORCH_CHECK(t->device().is_cpu() && t->is_contiguous(), "abcgs sh_colors: tensors must be contiguous CPU tensors");
  }
  const int64_t n = sh0.size(0);
  TORCH_CHECK(degree >= 0 && degree <= 3, "SH degree must be 0..3");
  TORCH_CHECK(sh0.dim() == 3 && sh0.size(1) == 1 && sh0.size(2) == 3, "sh0 must be (N, 1, 3)");
  TORCH_CHECK(shN.dim() == 3 && shN.size(0) == n && shN.size(2) == 3, "shN must be (N, K - 1, 3)");
  TORCH_CHECK((degree + 1) * (degree + 1) <= 1 + shN.size(1), "fewer SH coefficients than the degree needs");
  TORCH_CHECK(means.dim() == 2 && means.size(0) == n && means.size(1) == 3, "means must be (N, 3)");
  TORCH_CHECK(campos.numel() == 3, "campos must be (3,)");
  TORCH_CHECK(mask.scalar_type() == at::kBool && mask.numel() == n, "mask must be (N,) bool");
  for (const auto* t : {&shN, &means, &campos}) {
    TORCH_CHECK(t->scalar_type() == sh0.scalar_type(), "abcgs sh_colors: all float inputs must share a dtype");
  }
}

}  // namespace

// colours (N, 3) = max(SH . coeffs + 0.5, 0) on the rows of `mask`, 0 elsewhere.
at::Tensor sh_colors_forward(const at::Tensor& sh0, const at::Tensor& shN, const at::Tensor& means,
                             const at::Tensor& campos, const at::Tensor& mask, int64_t degree) {
  check_sh_inputs(sh0, shN, means, campos, mask, degree);
  const int64_t n = sh0.size(0), kn = shN.size(1), nb = (degree + 1) * (degree + 1);
  at::Tensor colors = at::empty({n, 3}, sh0.options());
  AT_DISPATCH_FLOATING_TYPES(sh0.scalar_type(), "abcgs_sh_colors_forward", [&] {
    using T = scalar_t;
    const T *s0 = sh0.data_ptr<T>(), *sn = shN.data_ptr<T>(), *mp = means.data_ptr<T>(), *cp = campos.data_ptr<T>();
    const bool* mk = mask.data_ptr<bool>();
    T* out = colors.data_ptr<T>();
    abcgs::parallel_range(n, 16384, [&](int64_t begin, int64_t end) {
      T b[16], d[3];
      for (int64_t g = begin; g < end; ++g) {
        if (!mk[g]) {
          out[3 * g] = out[3 * g + 1] = out[3 * g + 2] = T(0);
          continue;
        }
        unit_dir(mp + 3 * g, cp, d);
        sh_basis<T>(degree, d[0], d[1], d[2], b);
        for (int64_t c = 0; c < 3; ++c) {
          T v = b[0] * s0[3 * g + c];
          for (int64_t k = 1; k < nb; ++k) v += b[k] * sn[(g * kn + (k - 1)) * 3 + c];
          v += T(0.5);
          out[3 * g + c] = v < T(0) ? T(0) : v;  // NaN stays NaN, as torch's clamp_min
        }
      }
    });
  });
  return colors;
}

// (v_sh0 (N, 1, 3), v_shN (N, K - 1, 3) or empty, v_means (N, 3) or empty) from v_colors (N, 3); the gradient of
// the clamp passes where SH + 0.5 >= 0, as torch's clamp_min.
std::vector<at::Tensor> sh_colors_backward(const at::Tensor& sh0, const at::Tensor& shN, const at::Tensor& means,
                                           const at::Tensor& campos, const at::Tensor& mask, int64_t degree,
                                           const at::Tensor& v_colors, bool need_shN, bool need_means) {
  check_sh_inputs(sh0, shN, means, campos, mask, degree);
  TORCH_CHECK(v_colors.is_contiguous() && v_colors.scalar_type() == sh0.scalar_type() &&
                  v_colors.numel() == 3 * sh0.size(0), "v_colors must be a contiguous (N, 3) tensor of sh0's dtype");
  const int64_t n = sh0.size(0), kn = shN.size(1), nb = (degree + 1) * (degree + 1);
  at::Tensor v_sh0 = at::empty_like(sh0);
  at::Tensor v_shN = need_shN ? at::zeros_like(shN) : at::empty({0}, sh0.options());
  at::Tensor v_means = need_means ? at::empty_like(means) : at::empty({0}, sh0.options());
  AT_DISPATCH_FLOATING_TYPES(sh0.scalar_type(), "abcgs_sh_colors_backward", [&] {
    using T = scalar_t;
    const T *s0 = sh0.data_ptr<T>(), *sn = shN.data_ptr<T>(), *mp = means.data_ptr<T>(), *cp = campos.data_ptr<T>();
    const T* vc = v_colors.data_ptr<T>();
    const bool* mk = mask.data_ptr<bool>();
    T* g0 = v_sh0.data_ptr<T>();
    T* gn = need_shN ? v_shN.data_ptr<T>() : nullptr;
    T* gm = need_means ? v_means.data_ptr<T>() : nullptr;
    abcgs::parallel_range(n, 16384, [&](int64_t begin, int64_t end) {
      T b[16], d[3], w[16], gd[3], vraw[3];
      for (int64_t g = begin; g < end; ++g) {
        if (!mk[g]) {
          g0[3 * g] = g0[3 * g + 1] = g0[3 * g + 2] = T(0);
          if (gm) gm[3 * g] = gm[3 * g + 1] = gm[3 * g + 2] = T(0);
          continue;
        }
        const T len = unit_dir(mp + 3 * g, cp, d);
        sh_basis<T>(degree, d[0], d[1], d[2], b);
        bool any = false;
        for (int64_t c = 0; c < 3; ++c) {
          T v = b[0] * s0[3 * g + c];
          for (int64_t k = 1; k < nb; ++k) v += b[k] * sn[(g * kn + (k - 1)) * 3 + c];
          vraw[c] = v + T(0.5) >= T(0) ? vc[3 * g + c] : T(0);
          any |= vraw[c] != T(0);
        }
        for (int64_t c = 0; c < 3; ++c) g0[3 * g + c] = b[0] * vraw[c];
        if (gn && any) {
          for (int64_t k = 1; k < nb; ++k)
            for (int64_t c = 0; c < 3; ++c) gn[(g * kn + (k - 1)) * 3 + c] = b[k] * vraw[c];
        }
        if (!gm) continue;
        // basis weights w_k = sum_c coeff_kc v_c, then through dir = v / |v|: (I - d d^T) / |v|
        for (int64_t k = 1; k < nb; ++k) {
          w[k] = T(0);
          for (int64_t c = 0; c < 3; ++c) w[k] += coeff(s0, sn, kn, g, k, c) * vraw[c];
        }
        sh_basis_grad<T>(degree, d[0], d[1], d[2], w, gd);
        const T dot = d[0] * gd[0] + d[1] * gd[1] + d[2] * gd[2];
        for (int64_t i = 0; i < 3; ++i) gm[3 * g + i] = (gd[i] - d[i] * dot) / len;
      }
    });
  });
  return {v_sh0, v_shN, v_means};
}
