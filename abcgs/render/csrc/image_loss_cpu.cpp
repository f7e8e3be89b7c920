// Fused 3DGS photometric loss on the CPU: mean L1 and mean SSIM of a rendered image against its target,
// with their gradients with respect to the render, in two passes over the image (abcgs/fit/losses.py).
//
// SSIM is the 3DGS one (abcgs/fit/losses.py ssim_map): 11-tap Gaussian window (std 1.5 px) applied as a
// separable filter with zero padding, C1 = 0.01^2, C2 = 0.03^2, averaged over every pixel and channel.
// Written with torch ops, forward and backward of that loss are ~20 elementwise passes and four depthwise
// convolutions over the image, ~60 ms of a ~250 ms fit step on fern (497x373) with one torch thread; here
// they are two passes over row blocks, on the kernels' own threads.
//
// Per pixel, with mu = G*x, e11 = G*x^2, e12 = G*(x y) (G the window) and
//   A1 = 2 mu1 mu2 + C1, A2 = 2 (e12 - mu1 mu2) + C2, B1 = mu1^2 + mu2^2 + C1, B2 = e11 - mu1^2 + e22 - mu2^2 + C2,
//   S = A1 A2 / (B1 B2),
// the derivatives of S with respect to the filtered maps are
//   dS/dmu1 = 2 mu2 (A2 - A1) / (B1 B2) + 2 mu1 S (1/B2 - 1/B1),  dS/de11 = -S / B2,  dS/de12 = 2 A1 / (B1 B2),
// and, G being symmetric with zero padding (its own adjoint), the gradient of mean(S) with respect to x is
//   (G * dS/dmu1 + 2 x G * dS/de11 + y G * dS/de12) / n.
// Pass 1 computes S and the three derivative maps per row block (horizontal filter of the block's rows plus a
// 5-row halo, then vertical); pass 2 filters the derivative maps the same way and combines them.
//
// Determinism: every output element is written by one block, and the sums (L1, SSIM) are accumulated per
// block in double and added in block order, so results do not depend on the thread count.
#include "torch_api.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "parallel.h"

namespace {

constexpr int64_t kRowBlock = 32;

// out[j] = sum_t g[t] in[j + t - R] for j in [0, W), zero outside [0, W); `pad` holds W + 2R values.
template <typename scalar_t>
inline void filter_row(const scalar_t* in, int64_t W, const scalar_t* g, int64_t R, scalar_t* pad,
                       scalar_t* out) {
  std::fill(pad, pad + R, scalar_t(0));
  std::copy(in, in + W, pad + R);
  std::fill(pad + R + W, pad + W + 2 * R, scalar_t(0));
  std::fill(out, out + W, scalar_t(0));
  for (int64_t t = 0; t <= 2 * R; ++t) {
    const scalar_t w = g[t];
    const scalar_t* src = pad + t;
    for (int64_t j = 0; j < W; ++j) out[j] += w * src[j];
  }
}

// Vertical filter of `maps` row-filtered maps held for rows [h0, h1) (`rows`: maps x (h1 - h0) x W values)
// into output row r: out[m][j] = sum_t g[t] rows[m][r + t - R][j], rows outside [h0, h1) being zero (callers
// hold every image row in [r - R, r + R], so only image borders are cut).
template <typename scalar_t>
inline void filter_column(const scalar_t* rows, int64_t maps, int64_t h0, int64_t h1, int64_t W, int64_t r,
                          const scalar_t* g, int64_t R, scalar_t* out) {
  const int64_t span = h1 - h0;
  for (int64_t m = 0; m < maps; ++m) {
    scalar_t* o = out + m * W;
    std::fill(o, o + W, scalar_t(0));
    for (int64_t t = 0; t <= 2 * R; ++t) {
      const int64_t rr = r + t - R;
      if (rr < h0 || rr >= h1) continue;
      const scalar_t w = g[t];
      const scalar_t* src = rows + (m * span + (rr - h0)) * W;
      for (int64_t j = 0; j < W; ++j) o[j] += w * src[j];
    }
  }
}

// acc[k] += row[j] for j = k mod kSumLanes, in float64: a fixed summation order that vectorises without -ffast-math.
constexpr int kSumLanes = 8;
template <typename scalar_t>
inline void add_row(const scalar_t* row, int64_t W, double* acc) {
  int64_t j = 0;
  for (; j + kSumLanes <= W; j += kSumLanes)
    for (int k = 0; k < kSumLanes; ++k) acc[k] += double(row[j + k]);
  for (int k = 0; j < W; ++j, ++k) acc[k] += double(row[j]);
}

// One row of pass 1 (branch-free, vectorised): from the filtered statistics `stats` (mu1, mu2, e11, e22, e12,
// W values each) and the pixels xs, ys, the SSIM values S, the derivatives dS/dmu1, dS/de11, dS/de12, |x - y|
// and the L1 gradient sign(x - y) / n.
template <typename scalar_t>
inline void ssim_row(int64_t W, const scalar_t* __restrict stats, const scalar_t* __restrict xs,
                     const scalar_t* __restrict ys, scalar_t C1, scalar_t C2, scalar_t inv_n, scalar_t* __restrict s,
                     scalar_t* __restrict d_mu, scalar_t* __restrict d_e11, scalar_t* __restrict d_e12,
                     scalar_t* __restrict l1, scalar_t* __restrict l1_grad) {
  const scalar_t *mu1 = stats, *mu2 = mu1 + W, *e11 = mu2 + W, *e22 = e11 + W, *e12 = e22 + W;
  for (int64_t j = 0; j < W; ++j) {
    const scalar_t m1s = mu1[j] * mu1[j], m2s = mu2[j] * mu2[j], m12 = mu1[j] * mu2[j];
    const scalar_t A1 = 2 * m12 + C1, A2 = 2 * (e12[j] - m12) + C2;
    const scalar_t B1 = m1s + m2s + C1, B2 = (e11[j] - m1s) + (e22[j] - m2s) + C2;
    const scalar_t D = B1 * B2, S = (A1 * A2) / D;
    s[j] = S;
    d_mu[j] = 2 * mu2[j] * (A2 - A1) / D + 2 * mu1[j] * S * (1 / B2 - 1 / B1);
    d_e11[j] = -S / B2;
    d_e12[j] = 2 * A1 / D;
    const scalar_t diff = xs[j] - ys[j];
    l1[j] = std::abs(diff);
    l1_grad[j] = diff > 0 ? inv_n : diff < 0 ? -inv_n : scalar_t(0);
  }
}

template <typename scalar_t>
struct Planes {
  const scalar_t* x;  // render, (B, H, W, C) channels-last
  const scalar_t* y;  // target
  int64_t H, W, C;
  // Offset of element (r, 0) of plane p = b * C + c; the row's elements are C apart.
  int64_t row(int64_t p, int64_t r) const { return ((p / C) * H + r) * W * C + p % C; }
  // Row r of plane p of both images, gathered into contiguous buffers.
  void gather(int64_t p, int64_t r, scalar_t* xs, scalar_t* ys) const {
    const scalar_t *xp = x + row(p, r), *yp = y + row(p, r);
    for (int64_t j = 0; j < W; ++j) {
      xs[j] = xp[j * C];
      ys[j] = yp[j * C];
    }
  }
};

}  // namespace

// Returns (l1 (0-d, float64), ssim (0-d, float64), d l1 / d render, d ssim / d render), both gradients shaped
// like `render`. `window` is the normalised 1-D filter (odd length), in the render's dtype.
std::vector<at::Tensor> l1_ssim_forward(const at::Tensor& render, const at::Tensor& target, const at::Tensor& window,
                                        double c1, double c2) {
  TORCH_CHECK(render.device().is_cpu() && target.device().is_cpu(), "l1_ssim: CPU tensors expected");
  TORCH_CHECK(render.sizes() == target.sizes(), "l1_ssim: render and target must have the same shape");
  TORCH_CHECK(render.dim() == 3 || render.dim() == 4, "l1_ssim: (H, W, C) or (B, H, W, C) images expected");
  TORCH_CHECK(render.scalar_type() == target.scalar_type() && render.scalar_type() == window.scalar_type(),
              "l1_ssim: render, target and window must share a dtype");
  TORCH_CHECK(window.dim() == 1 && window.numel() % 2 == 1, "l1_ssim: an odd-length 1-D window expected");
  const at::Tensor xr = render.contiguous(), yr = target.contiguous(), gw = window.contiguous();
  const int64_t B = xr.dim() == 4 ? xr.size(0) : 1;
  const int64_t H = xr.size(-3), W = xr.size(-2), C = xr.size(-1);
  const int64_t R = gw.numel() / 2, n = xr.numel(), planes = B * C;
  const int64_t blocks_per_plane = (H + kRowBlock - 1) / kRowBlock, items = planes * blocks_per_plane;
  at::Tensor grad_l1 = at::empty_like(xr), grad_ssim = at::empty_like(xr);
  std::vector<double> l1_sums(items, 0.0), ssim_sums(items, 0.0);

  AT_DISPATCH_FLOATING_TYPES(xr.scalar_type(), "abcgs_l1_ssim", [&] {
    const Planes<scalar_t> im{xr.data_ptr<scalar_t>(), yr.data_ptr<scalar_t>(), H, W, C};
    const scalar_t* g = gw.data_ptr<scalar_t>();
    scalar_t* gl1 = grad_l1.data_ptr<scalar_t>();
    scalar_t* gss = grad_ssim.data_ptr<scalar_t>();
    const scalar_t C1 = scalar_t(c1), C2 = scalar_t(c2), inv_n = scalar_t(1.0 / double(n));
    // dS/dmu1, dS/de11, dS/de12 of every pixel, plane-major (3 x planes x H x W).
    std::vector<scalar_t> deriv(3 * planes * H * W);
    const int64_t plane_size = H * W;

    // Pass 1: filtered statistics, S, its derivatives, and the L1 term.
    abcgs::parallel_items(items, [&](int64_t item) {
      const int64_t p = item / blocks_per_plane, r0 = (item % blocks_per_plane) * kRowBlock;
      const int64_t r1 = std::min(H, r0 + kRowBlock), h0 = std::max<int64_t>(0, r0 - R),
                    h1 = std::min(H, r1 + R), span = h1 - h0;
      std::vector<scalar_t> rows(5 * span * W), xs(W), ys(W), prod(3 * W), pad(W + 2 * R), stats(5 * W), s_row(W),
          l_row(W), sign(W);
      scalar_t *xx = prod.data(), *yy = xx + W, *xy = yy + W;
      for (int64_t r = h0; r < h1; ++r) {
        im.gather(p, r, xs.data(), ys.data());
        for (int64_t j = 0; j < W; ++j) {
          xx[j] = xs[j] * xs[j];
          yy[j] = ys[j] * ys[j];
          xy[j] = xs[j] * ys[j];
        }
        const scalar_t* src[5] = {xs.data(), ys.data(), xx, yy, xy};
        for (int64_t m = 0; m < 5; ++m)
          filter_row(src[m], W, g, R, pad.data(), rows.data() + (m * span + (r - h0)) * W);
      }
      double s_acc[kSumLanes] = {}, l_acc[kSumLanes] = {};
      for (int64_t r = r0; r < r1; ++r) {
        filter_column(rows.data(), 5, h0, h1, W, r, g, R, stats.data());
        scalar_t* d_mu = deriv.data() + p * plane_size + r * W;
        scalar_t* d_e11 = d_mu + planes * plane_size;
        scalar_t* d_e12 = d_e11 + planes * plane_size;
        im.gather(p, r, xs.data(), ys.data());
        scalar_t* out_l1 = gl1 + im.row(p, r);
        ssim_row(W, stats.data(), xs.data(), ys.data(), C1, C2, inv_n, s_row.data(), d_mu, d_e11, d_e12,
                 l_row.data(), sign.data());
        add_row(s_row.data(), W, s_acc);
        add_row(l_row.data(), W, l_acc);
        for (int64_t j = 0; j < W; ++j) out_l1[j * C] = sign[j];
      }
      double s_sum = 0.0, l_sum = 0.0;
      for (int k = 0; k < kSumLanes; ++k) {
        s_sum += s_acc[k];
        l_sum += l_acc[k];
      }
      ssim_sums[item] = s_sum;
      l1_sums[item] = l_sum;
    });

    // Pass 2: d mean(S) / dx = (G * dS/dmu1 + 2 x G * dS/de11 + y G * dS/de12) / n.
    abcgs::parallel_items(items, [&](int64_t item) {
      const int64_t p = item / blocks_per_plane, r0 = (item % blocks_per_plane) * kRowBlock;
      const int64_t r1 = std::min(H, r0 + kRowBlock), h0 = std::max<int64_t>(0, r0 - R),
                    h1 = std::min(H, r1 + R), span = h1 - h0;
      std::vector<scalar_t> rows(3 * span * W), pad(W + 2 * R), filt(3 * W), xs(W), ys(W);
      for (int64_t r = h0; r < h1; ++r)
        for (int64_t m = 0; m < 3; ++m)
          filter_row(deriv.data() + (m * planes + p) * plane_size + r * W, W, g, R, pad.data(),
                     rows.data() + (m * span + (r - h0)) * W);
      for (int64_t r = r0; r < r1; ++r) {
        filter_column(rows.data(), 3, h0, h1, W, r, g, R, filt.data());
        im.gather(p, r, xs.data(), ys.data());
        scalar_t* out = gss + im.row(p, r);
        for (int64_t j = 0; j < W; ++j)
          out[j * C] = (filt[j] + 2 * xs[j] * filt[W + j] + ys[j] * filt[2 * W + j]) * inv_n;
      }
    });
  });

  double l1 = 0.0, ssim = 0.0;
  for (int64_t i = 0; i < items; ++i) {
    l1 += l1_sums[i];
    ssim += ssim_sums[i];
  }
  const auto scalar = at::TensorOptions().dtype(at::kDouble);
  return {at::scalar_tensor(l1 / double(n), scalar), at::scalar_tensor(ssim / double(n), scalar), grad_l1,
          grad_ssim};
}
