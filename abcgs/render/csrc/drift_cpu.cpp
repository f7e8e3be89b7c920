// Eq. 8's geometry terms of the stylization (abcgs/losses/drift.py): how far every Gaussian's scale and opacity
// have moved from the start, averaged, with the gradient, in one pass over the Gaussians. Written with torch ops,
// the two terms and their backward are about twenty passes over (N, 3) and (N,) tensors; here one pass each, on the
// kernels' threads.
//
//   scale:   L = mean_i ||exp(l_i) - exp(l0_i)||,   dL/dl_i = exp(l_i) d_i / (N ||d_i||), d_i = exp(l_i) - exp(l0_i)
//            (0 where the norm is 0, as torch's norm backward);
//   opacity: L = mean_i |s(z_i) - s(z0_i)|,   dL/dz_i = sign(s(z_i) - s(z0_i)) s(z_i) (1 - s(z_i)) / N, s = sigmoid
//            (sign(0) = 0, as torch's abs backward).
// The start (l0, z0) is activated here by the same code as the current values, so that a Gaussian that has not
// moved has a drift of exactly 0.
//
// Work goes in chunks of kDriftChunk Gaussians through flat loops that vectorise: float uses exp_fast (fast_exp.h,
// ~1e-7 relative), and a chunk with an input outside (-87, 87) (or NaN) uses std::exp instead;
// double always uses std::exp.
//
// Determinism: the terms are summed per chunk in double, in index order, and the chunks' sums are added in chunk
// order, so the value does not depend on the thread count; each gradient element is written by one chunk.
#include "torch_api.h"

#include <algorithm>
#include <cmath>
#include <type_traits>
#include <vector>

#include "fast_exp.h"
#include "parallel.h"

namespace {

constexpr int64_t kDriftChunk = 2048;

template <bool kFast, typename scalar_t>
inline scalar_t drift_exp(scalar_t x) {
  if constexpr (kFast) return abcgs::exp_fast(x);
  else return std::exp(x);
}

// Whether every value of v[0, n) lies in (-87, 87), where exp_fast of it and of its negative is exact to ~1e-7
// (false for NaN).
template <typename scalar_t>
inline bool in_fast_range(const scalar_t* v, int64_t n) {
  int outside = 0;
  for (int64_t i = 0; i < n; ++i) outside |= !(v[i] > scalar_t(-87) && v[i] < scalar_t(87));
  return outside == 0;
}

// chunk(c, fast) -> the chunk's summed terms, for every chunk c of n values, in parallel; their sum in chunk order.
template <typename F>
double sum_chunks(int64_t n, const F& chunk) {
  const int64_t chunks = (n + kDriftChunk - 1) / kDriftChunk;
  std::vector<double> sums(chunks, 0.0);
  abcgs::parallel_range(chunks, 8, [&](int64_t c0, int64_t c1) {
    for (int64_t c = c0; c < c1; ++c) sums[c] = chunk(c);
  });
  double total = 0.0;
  for (double s : sums) total += s;
  return total;
}

// One chunk of the scale drift: Gaussians [i0, i0 + m), writing their gradient rows; returns their summed norms.
template <bool kFast, typename scalar_t>
double scale_chunk(const scalar_t* l, const scalar_t* l0, scalar_t* g, int64_t i0, int64_t m, scalar_t inv_n) {
  alignas(64) scalar_t e[3 * kDriftChunk], d[3 * kDriftChunk], coef[kDriftChunk];
  const scalar_t* lp = l + 3 * i0;
  const scalar_t* l0p = l0 + 3 * i0;
  for (int64_t j = 0; j < 3 * m; ++j) {
    e[j] = drift_exp<kFast>(lp[j]);
    d[j] = e[j] - drift_exp<kFast>(l0p[j]);
  }
  double sum = 0.0;
  for (int64_t i = 0; i < m; ++i) {
    const scalar_t norm = std::sqrt(d[3 * i] * d[3 * i] + d[3 * i + 1] * d[3 * i + 1] + d[3 * i + 2] * d[3 * i + 2]);
    coef[i] = norm > scalar_t(0) ? inv_n / norm : scalar_t(0);
    sum += static_cast<double>(norm);
  }
  scalar_t* gp = g + 3 * i0;
  for (int64_t j = 0; j < 3 * m; ++j) gp[j] = coef[j / 3] * d[j] * e[j];
  return sum;
}

// One chunk of the opacity drift: Gaussians [i0, i0 + m), writing their gradients; returns their summed |drift|.
template <bool kFast, typename scalar_t>
double opacity_chunk(const scalar_t* z, const scalar_t* z0, scalar_t* g, int64_t i0, int64_t m, scalar_t inv_n) {
  alignas(64) scalar_t a[kDriftChunk];
  const scalar_t one(1), zero(0);
  for (int64_t i = 0; i < m; ++i) {
    const scalar_t o = one / (one + drift_exp<kFast>(-z[i0 + i]));
    const scalar_t d = o - one / (one + drift_exp<kFast>(-z0[i0 + i]));
    const scalar_t sign = d > zero ? one : (d < zero ? -one : zero);
    g[i0 + i] = sign * o * (one - o) * inv_n;
    a[i] = std::abs(d);
  }
  double sum = 0.0;
  for (int64_t i = 0; i < m; ++i) sum += static_cast<double>(a[i]);
  return sum;
}

// The chunk [c * kDriftChunk, ...) of `count` Gaussians of `width` values each through `body<fast>`: the fast
// exponential for float inputs inside its range, std::exp otherwise.
template <typename scalar_t, typename B>
double drift_chunk(const scalar_t* x, const scalar_t* x0, int64_t c, int64_t count, int64_t width, const B& body) {
  const int64_t i0 = c * kDriftChunk, m = std::min(kDriftChunk, count - i0);
  if constexpr (std::is_same_v<scalar_t, float>) {
    if (in_fast_range(x + width * i0, width * m) && in_fast_range(x0 + width * i0, width * m))
      return body(std::true_type{}, i0, m);
  }
  return body(std::false_type{}, i0, m);
}

}  // namespace

// mean_i ||exp(log_scales_i) - exp(start_i)|| of (N, 3) log-scales and the start's: (value (0-d, double), gradient
// w.r.t. log_scales (N, 3), the log-scales' dtype).
std::vector<at::Tensor> scale_drift(const at::Tensor& log_scales, const at::Tensor& start) {
  TORCH_CHECK(log_scales.dim() == 2 && log_scales.size(1) == 3 && start.sizes() == log_scales.sizes(),
              "scale_drift: the log-scales and the start's must both be (N, 3)");
  TORCH_CHECK(log_scales.device().is_cpu() && start.scalar_type() == log_scales.scalar_type(),
              "scale_drift: CPU tensors of one dtype");
  const at::Tensor l = log_scales.contiguous(), l0 = start.contiguous();
  const int64_t n = l.size(0);
  at::Tensor grad = at::empty_like(l);
  double total = 0.0;
  AT_DISPATCH_FLOATING_TYPES(l.scalar_type(), "abcgs_scale_drift", [&] {
    const scalar_t* lp = l.data_ptr<scalar_t>();
    const scalar_t* l0p = l0.data_ptr<scalar_t>();
    scalar_t* gp = grad.data_ptr<scalar_t>();
    const scalar_t inv_n = n > 0 ? scalar_t(1) / scalar_t(n) : scalar_t(0);
    total = sum_chunks(n, [&](int64_t c) {
      return drift_chunk(lp, l0p, c, n, 3, [&](auto fast, int64_t i0, int64_t m) {
        return scale_chunk<decltype(fast)::value>(lp, l0p, gp, i0, m, inv_n);
      });
    });
  });
  return {at::scalar_tensor(n > 0 ? total / double(n) : 0.0, at::kDouble), grad};
}

// mean_i |sigmoid(logits_i) - sigmoid(start_i)| of (N,) opacity logits and the start's: (value (0-d, double),
// gradient w.r.t. the logits (N,), their dtype).
std::vector<at::Tensor> opacity_drift(const at::Tensor& logits, const at::Tensor& start) {
  TORCH_CHECK(logits.dim() == 1 && start.sizes() == logits.sizes(),
              "opacity_drift: the logits and the start's must both be (N,)");
  TORCH_CHECK(logits.device().is_cpu() && start.scalar_type() == logits.scalar_type(),
              "opacity_drift: CPU tensors of one dtype");
  const at::Tensor z = logits.contiguous(), z0 = start.contiguous();
  const int64_t n = z.size(0);
  at::Tensor grad = at::empty_like(z);
  double total = 0.0;
  AT_DISPATCH_FLOATING_TYPES(z.scalar_type(), "abcgs_opacity_drift", [&] {
    const scalar_t* zp = z.data_ptr<scalar_t>();
    const scalar_t* z0p = z0.data_ptr<scalar_t>();
    scalar_t* gp = grad.data_ptr<scalar_t>();
    const scalar_t inv_n = n > 0 ? scalar_t(1) / scalar_t(n) : scalar_t(0);
    total = sum_chunks(n, [&](int64_t c) {
      return drift_chunk(zp, z0p, c, n, 1, [&](auto fast, int64_t i0, int64_t m) {
        return opacity_chunk<decltype(fast)::value>(zp, z0p, gp, i0, m, inv_n);
      });
    });
  });
  return {at::scalar_tensor(n > 0 ? total / double(n) : 0.0, at::kDouble), grad};
}
