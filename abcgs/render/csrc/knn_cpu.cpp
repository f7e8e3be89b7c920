// Similarity-search helpers of the k-nearest-neighbour losses (abcgs/style/knn.py).
//
// Dot products of selected row pairs: out[p] = <a[ia[p]], b[ib[p]]> for row-major a (Na, C), b (Nb, C).
//
// Used by the certified bf16 nearest-neighbour search (abcgs/style/knn.py) to re-rank a few candidates per
// feature exactly, without gathering the candidates' C-dimensional rows into a new tensor first (torch's
// index_select + bmm moved ~30 MB per candidate slot through memory on fern). Lives in the CPU kernels'
// extension so that it shares their build and thread pool; it is not a rendering kernel.
//
// Sixteen independent float accumulators (a vectorisable pattern without -ffast-math), summed at the end.
// Every pair is written by exactly one worker: results do not depend on the thread count.
#include <torch/extension.h>

#include <limits>
#include <vector>

#include "parallel.h"

at::Tensor pair_dots(const at::Tensor& a, const at::Tensor& b, const at::Tensor& ia, const at::Tensor& ib) {
  TORCH_CHECK(a.dim() == 2 && b.dim() == 2 && a.size(1) == b.size(1), "pair_dots: a (Na, C) and b (Nb, C) expected");
  TORCH_CHECK(a.scalar_type() == at::kFloat && b.scalar_type() == at::kFloat, "pair_dots: float32 rows expected");
  TORCH_CHECK(ia.dim() == 1 && ib.dim() == 1 && ia.numel() == ib.numel(), "pair_dots: equally long index lists");
  TORCH_CHECK(ia.scalar_type() == at::kLong && ib.scalar_type() == at::kLong, "pair_dots: int64 indices expected");
  const at::Tensor ac = a.contiguous(), bc = b.contiguous(), iac = ia.contiguous(), ibc = ib.contiguous();
  const int64_t n_a = ac.size(0), n_b = bc.size(0), C = ac.size(1), P = iac.numel();
  at::Tensor out = at::empty({P}, ac.options());
  const float* pa = ac.data_ptr<float>();
  const float* pb = bc.data_ptr<float>();
  const int64_t* pia = iac.data_ptr<int64_t>();
  const int64_t* pib = ibc.data_ptr<int64_t>();
  float* po = out.data_ptr<float>();
  for (int64_t p = 0; p < P; ++p) {
    TORCH_CHECK(pia[p] >= 0 && pia[p] < n_a && pib[p] >= 0 && pib[p] < n_b, "pair_dots: index out of range");
  }
  constexpr int64_t L = 16;
  abcgs::parallel_range(P, 1024, [&](int64_t begin, int64_t end) {
    for (int64_t p = begin; p < end; ++p) {
      const float* x = pa + pia[p] * C;
      const float* y = pb + pib[p] * C;
      float acc[L] = {0.f};
      int64_t c = 0;
      for (; c + L <= C; c += L) {
        for (int64_t l = 0; l < L; ++l) acc[l] += x[c + l] * y[c + l];
      }
      float s = 0.f;
      for (; c < C; ++c) s += x[c] * y[c];
      for (int64_t l = 0; l < L; ++l) s += acc[l];
      po[p] = s;
    }
  });
  return out;
}

// Top-k of every column of a row-major (n, m) matrix (float32 or bfloat16): values (k, m) float32 and row
// indices (k, m) int64, largest first. One pass over the rows in memory order; each column keeps a sorted
// list of its k best, entered only when a value beats the list's last (after the first rows, rarely), so the
// pass costs about one comparison per entry, where torch.topk(dim=0) walks the matrix with a stride of a row.
// Workers own disjoint column ranges (results do not depend on the thread count); ties keep the earlier row.
template <typename T>
static void topk_columns_impl(const T* s, int64_t n, int64_t m, int64_t k, float* vals, int64_t* idx) {
  abcgs::parallel_range(m, 64, [&](int64_t j0, int64_t j1) {
    const int64_t w = j1 - j0;
    std::vector<float> best(static_cast<size_t>(w * k), -std::numeric_limits<float>::infinity());
    std::vector<int64_t> arg(static_cast<size_t>(w * k), -1);
    std::vector<float> thr(static_cast<size_t>(w), -std::numeric_limits<float>::infinity());
    for (int64_t i = 0; i < n; ++i) {
      const T* row = s + i * m + j0;
      for (int64_t j = 0; j < w; ++j) {
        const float x = static_cast<float>(row[j]);
        if (!(x > thr[j])) continue;
        float* b = best.data() + j * k;
        int64_t* a = arg.data() + j * k;
        int64_t p = k - 1;
        while (p > 0 && b[p - 1] < x) {
          b[p] = b[p - 1];
          a[p] = a[p - 1];
          --p;
        }
        b[p] = x;
        a[p] = i;
        thr[j] = b[k - 1];
      }
    }
    for (int64_t j = 0; j < w; ++j) {
      for (int64_t q = 0; q < k; ++q) {
        vals[q * m + j0 + j] = best[j * k + q];
        idx[q * m + j0 + j] = arg[j * k + q];
      }
    }
  });
}

std::vector<at::Tensor> topk_columns(const at::Tensor& s, int64_t k) {
  TORCH_CHECK(s.dim() == 2, "topk_columns: a (n, m) matrix expected");
  TORCH_CHECK(s.scalar_type() == at::kFloat || s.scalar_type() == at::kBFloat16, "topk_columns: float32 or bfloat16");
  const at::Tensor sc = s.contiguous();
  const int64_t n = sc.size(0), m = sc.size(1);
  TORCH_CHECK(k >= 1 && k <= n, "topk_columns: need 1 <= k <= rows, got k=", k, " rows=", n);
  at::Tensor vals = at::empty({k, m}, sc.options().dtype(at::kFloat));
  at::Tensor idx = at::empty({k, m}, sc.options().dtype(at::kLong));
  if (sc.scalar_type() == at::kFloat) {
    topk_columns_impl(sc.data_ptr<float>(), n, m, k, vals.data_ptr<float>(), idx.data_ptr<int64_t>());
  } else {
    topk_columns_impl(sc.data_ptr<at::BFloat16>(), n, m, k, vals.data_ptr<float>(), idx.data_ptr<int64_t>());
  }
  return {vals, idx};
}
