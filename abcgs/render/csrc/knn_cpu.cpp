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
#include "torch_api.h"

#include <algorithm>
#if defined(__AVX__)
#include <immintrin.h>
#endif
#include <limits>
#include <vector>

#include "parallel.h"

// <x, y> over C floats, summed in 16 interleaved partial sums (vectorisable without reassociation) and then the tail:
// one summation order for pair_dots and rerank_topk, so both give the same value for the same pair.
static inline float row_dot(const float* __restrict x, const float* __restrict y, int64_t C) {
  constexpr int64_t L = 16;
  float acc[L] = {0.f};
  int64_t c = 0;
  for (; c + L <= C; c += L) {
    for (int64_t l = 0; l < L; ++l) acc[l] += x[c + l] * y[c + l];
  }
  float s = 0.f;
  for (; c < C; ++c) s += x[c] * y[c];
  for (int64_t l = 0; l < L; ++l) s += acc[l];
  return s;
}

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
  abcgs::parallel_range(P, 1024, [&](int64_t begin, int64_t end) {
    for (int64_t p = begin; p < end; ++p) {
      po[p] = row_dot(pa + pia[p] * C, pb + pib[p] * C, C);
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

// Candidate search of the projected nearest-neighbour search (abcgs/style/knn.py, Projection): the ka largest dot
// products of every row of a (Na, R) with the rows of b (Nb, R), and the kb largest of every row of b with the rows
// of a, without storing the Na x Nb products. They are computed in register tiles of 6 a-rows x 16 b-rows (a packed
// in 6-row blocks, b in 16-row panels) in two passes:
//  1. every tile once, keeping only maxima: per a-row and panel, and per b-row and block. The ka-th largest of an
//     a-row's panel maxima is a lower bound on its ka-th largest product (ka distinct panels hold a product at least
//     that large), so only panels whose maximum reaches it can hold the row's ka best; likewise for b-rows.
//  2. the tiles that can hold a row's best are computed again (the same arithmetic, so the same values), and only
//     products at or above the bound enter the rows' lists. On fern's photos x Starry Night (rank 128, 16
//     candidates) 14 % of the tiles are computed again for the a-rows and 22 % for the b-rows.
// Returns {a_idx (Na, ka) int64, a_val (Na, ka) float32, b_idx (Nb, kb), b_val (Nb, kb)}, largest first; ka or kb
// may be 0 (that direction is skipped and its outputs are empty).
//
// bf16_products: the products are taken of a and b rounded to bfloat16 (round to nearest even), summed in float32 by
// the AVX512-BF16 pair dot product (vdpbf16ps: two bf16 products per float32 lane and instruction, twice the
// multiply-adds of a float32 FMA of the same width). Only the candidates' order changes (the values are
// approximations of float32 dot products either way, and the caller re-ranks the candidates exactly); the tile layout,
// the bounds and the passes are the same. Available where the extension was compiled for a CPU with AVX512-BF16 and
// AVX512-VL (bf16_dot_available()).
//
// Determinism: every product is summed over R in the same order whatever the thread count; each list is built by one
// worker (a-rows by blocks, b-rows by panels), and ties keep the lower index, so results do not depend on the
// thread count.
namespace {

constexpr int64_t kTileA = 6;         // a-rows per register tile
constexpr int64_t kTileB = 16;        // b-rows per packed panel (two 8-lane vectors)
constexpr int64_t kChunkPanels = 32;  // panels per cache block of pass 1 (32 x 16 rows x R floats: 256 KiB at R = 128)

typedef float vf8 __attribute__((vector_size(32)));

inline vf8 load8(const float* p) {
  vf8 v;
  __builtin_memcpy(&v, p, sizeof(v));
  return v;
}

// Top-k lists of many rows: a min-heap of k entries per row whose root is the worst kept entry, and each row's
// current threshold (the root's value; -inf until k entries arrived). Order: larger value first, ties to the lower
// index, so the lists hold each row's k best in that order whatever order the entries arrive in.
class TopLists {
 public:
  TopLists(int64_t rows, int64_t k)
      : k_(k), val_(static_cast<size_t>(rows * k), -std::numeric_limits<float>::infinity()),
        idx_(static_cast<size_t>(rows * k), std::numeric_limits<int64_t>::max()),
        thr_(static_cast<size_t>(rows), -std::numeric_limits<float>::infinity()) {}

  void push(int64_t row, float x, int64_t idx) {
    if (!(x >= thr_[row])) return;
    float* v = val_.data() + row * k_;
    int64_t* id = idx_.data() + row * k_;
    if (!worse(v[0], id[0], x, idx)) return;  // equal to the root and not a lower index
    int64_t p = 0;  // sift the new entry down from the root
    for (;;) {
      int64_t c = 2 * p + 1;
      if (c >= k_) break;
      if (c + 1 < k_ && worse(v[c + 1], id[c + 1], v[c], id[c])) ++c;
      if (!worse(v[c], id[c], x, idx)) break;
      v[p] = v[c];
      id[p] = id[c];
      p = c;
    }
    v[p] = x;
    id[p] = idx;
    thr_[row] = v[0];
  }

  // The row's k best, best first (entries never filled: -inf and index -1).
  void emit(int64_t row, float* val, int64_t* idx) const {
    std::vector<std::pair<float, int64_t>> e(static_cast<size_t>(k_));
    for (int64_t q = 0; q < k_; ++q) e[q] = {val_[row * k_ + q], idx_[row * k_ + q]};
    std::sort(e.begin(), e.end(), [](const auto& x, const auto& y) { return worse(y.first, y.second, x.first, x.second); });
    for (int64_t q = 0; q < k_; ++q) {
      val[q] = e[q].first;
      idx[q] = e[q].second == std::numeric_limits<int64_t>::max() ? -1 : e[q].second;
    }
  }

 private:
  // (va, ia) ranks below (vb, ib): a smaller value, or an equal value with a larger index.
  static bool worse(float va, int64_t ia, float vb, int64_t ib) { return va < vb || (va == vb && ia > ib); }

  int64_t k_;
  std::vector<float> val_;
  std::vector<int64_t> idx_;
  std::vector<float> thr_;
};

// c[i][h] lanes l = <a-block row i, panel row 8h + l>; a_blk is (R, kTileA), panel (R, kTileB), both zero-padded.
// Twelve accumulators in registers (GCC/Clang vector extensions: 8-lane AVX where the target has it). With FMA
// (x86 -march=native on an FMA CPU) the multiply-adds are fused: twelve independent chains keep both FMA ports
// busy (42 GMAC/s on one core here, against 21 with eight chains or with separate multiplies and adds).
// The accumulators are locals of a function of their own (not inlined into the scan, which indexes the tile by
// lane and would otherwise keep it in memory through the loop over R).
struct Tile {
  vf8 c[kTileA][2];
};

__attribute__((noinline)) void dot_tile(const float* __restrict a_blk, const float* __restrict panel, int64_t R,
                                        Tile* __restrict out) {
  vf8 c[kTileA][2] = {};
  for (int64_t r = 0; r < R; ++r) {
    const vf8 b0 = load8(panel + r * kTileB), b1 = load8(panel + r * kTileB + 8);
    const float* ar = a_blk + r * kTileA;
    for (int i = 0; i < kTileA; ++i) {
#if defined(__FMA__) && defined(__AVX__)
      const __m256 ai = _mm256_set1_ps(ar[i]);
      c[i][0] = (vf8)_mm256_fmadd_ps(ai, (__m256)b0, (__m256)c[i][0]);
      c[i][1] = (vf8)_mm256_fmadd_ps(ai, (__m256)b1, (__m256)c[i][1]);
#else
      c[i][0] += ar[i] * b0;
      c[i][1] += ar[i] * b1;
#endif
    }
  }
  __builtin_memcpy(out->c, c, sizeof(c));
}

#if defined(__AVX512BF16__) && defined(__AVX512VL__)
#define ABCGS_BF16_DOT 1
// The bf16 tile: a_blk is (R2, kTileA, 2) and panel (R2, kTileB, 2) raw bf16 bits, R2 = ceil(R / 2), the pair
// (r = 2 r2, 2 r2 + 1) adjacent (zero-padded), so that one 32-bit broadcast of an a-row's pair and one 8-lane load of
// the panel give vdpbf16ps its operands: lane l of c[i][h] += a[i][2r2] b[8h+l][2r2] + a[i][2r2+1] b[8h+l][2r2+1].
// Twelve accumulator chains as in dot_tile, half the instructions per r.
__attribute__((noinline)) void dot_tile_bf16(const uint16_t* __restrict a_blk, const uint16_t* __restrict panel,
                                             int64_t R2, Tile* __restrict out) {
  __m256 c[kTileA][2];
  for (int i = 0; i < kTileA; ++i) c[i][0] = c[i][1] = _mm256_setzero_ps();
  for (int64_t r = 0; r < R2; ++r) {
    const __m256bh b0 = (__m256bh)_mm256_loadu_si256(reinterpret_cast<const __m256i*>(panel + r * kTileB * 2));
    const __m256bh b1 = (__m256bh)_mm256_loadu_si256(reinterpret_cast<const __m256i*>(panel + r * kTileB * 2 + 16));
    const uint16_t* ar = a_blk + r * kTileA * 2;
    for (int i = 0; i < kTileA; ++i) {
      uint32_t pair;
      __builtin_memcpy(&pair, ar + 2 * i, sizeof(pair));
      const __m256bh ai = (__m256bh)_mm256_set1_epi32(static_cast<int>(pair));
      c[i][0] = _mm256_dpbf16_ps(c[i][0], ai, b0);
      c[i][1] = _mm256_dpbf16_ps(c[i][1], ai, b1);
    }
  }
  __builtin_memcpy(out->c, c, sizeof(c));
}
#else
#define ABCGS_BF16_DOT 0
#endif

// Rows of x (n, R) packed into groups of `width` rows: (groups, R, width) float32, or with bf16 (groups, R2, width, 2)
// bfloat16 bits (round to nearest even; R2 = ceil(R / 2), pairs of r adjacent); zero-padded either way.
void pack_rows(const float* x, int64_t n, int64_t R, int64_t width, bool bf16, std::vector<float>& f32,
               std::vector<uint16_t>& b16) {
  const int64_t groups = (n + width - 1) / width;
  if (!bf16) {
    f32.assign(static_cast<size_t>(groups * R * width), 0.f);
    abcgs::parallel_range(n, 512, [&](int64_t i0, int64_t i1) {
      for (int64_t i = i0; i < i1; ++i) {
        float* dst = f32.data() + (i / width) * R * width + (i % width);
        for (int64_t r = 0; r < R; ++r) dst[r * width] = x[i * R + r];
      }
    });
    return;
  }
  const int64_t R2 = (R + 1) / 2;
  b16.assign(static_cast<size_t>(groups * R2 * width * 2), 0);
  abcgs::parallel_range(n, 512, [&](int64_t i0, int64_t i1) {
    for (int64_t i = i0; i < i1; ++i) {
      uint16_t* dst = b16.data() + (i / width) * R2 * width * 2 + (i % width) * 2;
      for (int64_t r = 0; r < R; ++r) dst[(r / 2) * width * 2 + (r % 2)] = c10::BFloat16(x[i * R + r]).x;
    }
  });
}

inline vf8 vmax(vf8 x, vf8 y) { return x > y ? x : y; }

// The k largest of a stream, kept sorted (largest first) in top[0..k): an entry enters only when it beats top[k-1],
// which after the first entries is rare (a branch the predictor gets right), unlike std::nth_element's partitions.
struct KLargest {
  float* top;
  int64_t k, n = 0;
  void add(float x) {
    if (n < k) {
      ++n;  // a free slot at the end
    } else if (!(x > top[k - 1])) {
      return;
    }
    int64_t p = n - 1;  // insert into the last slot (free, or the dropped k-th) and move x up to its place
    while (p > 0 && top[p - 1] < x) {
      top[p] = top[p - 1];
      --p;
    }
    top[p] = x;
  }
  float kth() const { return top[k - 1]; }
};

}  // namespace

bool bf16_dot_available() { return ABCGS_BF16_DOT != 0; }

std::vector<at::Tensor> topk_dots_both(const at::Tensor& a, const at::Tensor& b, int64_t ka, int64_t kb,
                                       bool bf16_products) {
  TORCH_CHECK(a.dim() == 2 && b.dim() == 2 && a.size(1) == b.size(1), "topk_dots_both: a (Na, R), b (Nb, R) expected");
  TORCH_CHECK(a.scalar_type() == at::kFloat && b.scalar_type() == at::kFloat, "topk_dots_both: float32 rows expected");
  TORCH_CHECK(!bf16_products || bf16_dot_available(),
              "topk_dots_both: bf16 products need a build for a CPU with AVX512-BF16 and AVX512-VL "
              "(bf16_dot_available() is false here)");
  const at::Tensor ac = a.contiguous(), bc = b.contiguous();
  const int64_t Na = ac.size(0), Nb = bc.size(0), R = ac.size(1);
  TORCH_CHECK(Na >= 1 && Nb >= 1, "topk_dots_both: empty input");
  TORCH_CHECK(ka >= 0 && ka <= Nb && kb >= 0 && kb <= Na && ka + kb > 0,
              "topk_dots_both: need 0 <= ka <= Nb, 0 <= kb <= Na, not both 0; got ka=", ka, " kb=", kb, " Na=", Na,
              " Nb=", Nb);
  const float* pa = ac.data_ptr<float>();
  const float* pb = bc.data_ptr<float>();
  const float neg_inf = -std::numeric_limits<float>::infinity();

  // Pack a into (blocks, R, kTileA) and b into (panels, R, kTileB), zero-padded (bf16: pairs of r, see pack_rows).
  const int64_t n_blocks = (Na + kTileA - 1) / kTileA, n_panels = (Nb + kTileB - 1) / kTileB;
  std::vector<float> a_pack, b_pack;
  std::vector<uint16_t> a_pack16, b_pack16;
  pack_rows(pa, Na, R, kTileA, bf16_products, a_pack, a_pack16);
  pack_rows(pb, Nb, R, kTileB, bf16_products, b_pack, b_pack16);
  const int64_t R2 = (R + 1) / 2;
  auto tile = [&](int64_t blk, int64_t p, Tile* t) {
#if ABCGS_BF16_DOT
    if (bf16_products) {
      dot_tile_bf16(a_pack16.data() + blk * R2 * kTileA * 2, b_pack16.data() + p * R2 * kTileB * 2, R2, t);
      return;
    }
#endif
    dot_tile(a_pack.data() + blk * R * kTileA, b_pack.data() + p * R * kTileB, R, t);
  };

  // Pass 1: maxima per (a-row, panel) and per (block, b-row); each block's rows and entries belong to one worker.
  std::vector<float> a_max(static_cast<size_t>(ka > 0 ? Na * n_panels : 0));
  std::vector<float> b_max(static_cast<size_t>(kb > 0 ? n_panels * n_blocks * kTileB : 0));  // (panel, block, lane)
  abcgs::parallel_range(n_blocks, 4, [&](int64_t blk0, int64_t blk1) {
    Tile t;
    for (int64_t c0 = 0; c0 < n_panels; c0 += kChunkPanels) {
      const int64_t c1 = std::min(n_panels, c0 + kChunkPanels);
      for (int64_t blk = blk0; blk < blk1; ++blk) {
        const int64_t i0 = blk * kTileA, mr = std::min(kTileA, Na - i0);
        for (int64_t p = c0; p < c1; ++p) {
          tile(blk, p, &t);
          const int64_t nr = std::min(kTileB, Nb - p * kTileB);
          for (int64_t i = 0; ka > 0 && i < mr; ++i) {
            float m = neg_inf;
            if (nr == kTileB) {
              const vf8 v = vmax(t.c[i][0], t.c[i][1]);
              for (int l = 0; l < 8; ++l) m = std::max(m, v[l]);
            } else {
              for (int64_t j = 0; j < nr; ++j) m = std::max(m, t.c[i][j >> 3][j & 7]);
            }
            a_max[(i0 + i) * n_panels + p] = m;
          }
          if (kb > 0) {
            vf8 m0 = t.c[0][0], m1 = t.c[0][1];
            for (int i = 1; i < mr; ++i) {
              m0 = vmax(m0, t.c[i][0]);
              m1 = vmax(m1, t.c[i][1]);
            }
            float* dst = b_max.data() + (p * n_blocks + blk) * kTileB;
            __builtin_memcpy(dst, &m0, sizeof(m0));
            __builtin_memcpy(dst + 8, &m1, sizeof(m1));
          }
        }
      }
    }
  });

  // Bounds: the ka-th largest panel maximum of each a-row, the kb-th largest block maximum of each b-row (-inf when
  // there are fewer panels or blocks than that: every tile is looked at).
  std::vector<float> a_bound(static_cast<size_t>(Na), neg_inf), b_bound(static_cast<size_t>(Nb), neg_inf);
  if (ka > 0 && ka <= n_panels) {
    abcgs::parallel_range(Na, 256, [&](int64_t i0, int64_t i1) {
      std::vector<float> top(static_cast<size_t>(ka));
      for (int64_t i = i0; i < i1; ++i) {
        KLargest best{top.data(), ka};
        for (int64_t p = 0; p < n_panels; ++p) best.add(a_max[i * n_panels + p]);
        a_bound[i] = best.kth();
      }
    });
  }
  if (kb > 0 && kb <= n_blocks) {
    abcgs::parallel_range(n_panels, 8, [&](int64_t p0, int64_t p1) {
      std::vector<float> top(static_cast<size_t>(kb * kTileB));
      for (int64_t p = p0; p < p1; ++p) {
        const int64_t nr = std::min(kTileB, Nb - p * kTileB);
        std::vector<KLargest> best;
        for (int64_t l = 0; l < nr; ++l) best.push_back(KLargest{top.data() + l * kb, kb});
        for (int64_t blk = 0; blk < n_blocks; ++blk) {
          const float* m = b_max.data() + (p * n_blocks + blk) * kTileB;
          for (int64_t l = 0; l < nr; ++l) best[l].add(m[l]);
        }
        for (int64_t l = 0; l < nr; ++l) b_bound[p * kTileB + l] = best[l].kth();
      }
    });
  }

  // Pass 2: recompute the tiles that can hold a list's entries; the products at or above the bound enter the lists.
  at::Tensor a_val = at::empty({Na, ka}, ac.options());
  at::Tensor a_idx = at::empty({Na, ka}, ac.options().dtype(at::kLong));
  if (ka > 0) {
    TopLists lists(Na, ka);
    abcgs::parallel_range(n_blocks, 4, [&](int64_t blk0, int64_t blk1) {
      Tile t;
      for (int64_t blk = blk0; blk < blk1; ++blk) {
        const int64_t i0 = blk * kTileA, mr = std::min(kTileA, Na - i0);
        for (int64_t p = 0; p < n_panels; ++p) {
          bool needed = false;
          for (int64_t i = 0; i < mr; ++i) needed |= a_max[(i0 + i) * n_panels + p] >= a_bound[i0 + i];
          if (!needed) continue;
          tile(blk, p, &t);
          const int64_t j0 = p * kTileB, nr = std::min(kTileB, Nb - j0);
          for (int64_t i = 0; i < mr; ++i) {
            if (!(a_max[(i0 + i) * n_panels + p] >= a_bound[i0 + i])) continue;
            for (int64_t j = 0; j < nr; ++j) {
              const float x = t.c[i][j >> 3][j & 7];
              if (x >= a_bound[i0 + i]) lists.push(i0 + i, x, j0 + j);
            }
          }
        }
      }
      for (int64_t i = blk0 * kTileA; i < std::min(Na, blk1 * kTileA); ++i)
        lists.emit(i, a_val.data_ptr<float>() + i * ka, a_idx.data_ptr<int64_t>() + i * ka);
    });
  }
  at::Tensor b_val = at::empty({Nb, kb}, ac.options());
  at::Tensor b_idx = at::empty({Nb, kb}, ac.options().dtype(at::kLong));
  if (kb > 0) {
    TopLists lists(Nb, kb);
    abcgs::parallel_range(n_panels, 4, [&](int64_t p0, int64_t p1) {
      Tile t;
      for (int64_t p = p0; p < p1; ++p) {
        const int64_t j0 = p * kTileB, nr = std::min(kTileB, Nb - j0);
        for (int64_t blk = 0; blk < n_blocks; ++blk) {
          const float* m = b_max.data() + (p * n_blocks + blk) * kTileB;
          bool needed = false;
          for (int64_t j = 0; j < nr; ++j) needed |= m[j] >= b_bound[j0 + j];
          if (!needed) continue;
          tile(blk, p, &t);
          const int64_t i0 = blk * kTileA, mr = std::min(kTileA, Na - i0);
          for (int64_t j = 0; j < nr; ++j) {
            if (!(m[j] >= b_bound[j0 + j])) continue;
            for (int64_t i = 0; i < mr; ++i) {
              const float x = t.c[i][j >> 3][j & 7];
              if (x >= b_bound[j0 + j]) lists.push(j0 + j, x, i0 + i);
            }
          }
        }
      }
      for (int64_t j = p0 * kTileB; j < std::min(Nb, p1 * kTileB); ++j)
        lists.emit(j, b_val.data_ptr<float>() + j * kb, b_idx.data_ptr<int64_t>() + j * kb);
    });
  }
  return {a_idx, a_val, b_idx, b_val};
}

// Exact re-ranking of candidates: for every row i of own (N, C), the k candidates cand[i] (indices into the rows of
// other (M, C)) with the largest dot products <own[i], other[cand[i][q]]>, largest first, ties to the lower index.
// The dot products are pair_dots' (row_dot). Rows are split between workers; results do not depend on the thread
// count. Used by the projected nearest-neighbour search after topk_dots_both (abcgs/style/knn.py).
at::Tensor rerank_topk(const at::Tensor& own, const at::Tensor& other, const at::Tensor& cand, int64_t k) {
  TORCH_CHECK(own.dim() == 2 && other.dim() == 2 && own.size(1) == other.size(1),
              "rerank_topk: own (N, C) and other (M, C) expected");
  TORCH_CHECK(own.scalar_type() == at::kFloat && other.scalar_type() == at::kFloat, "rerank_topk: float32 rows expected");
  TORCH_CHECK(cand.dim() == 2 && cand.size(0) == own.size(0) && cand.scalar_type() == at::kLong,
              "rerank_topk: cand (N, K) int64 expected");
  TORCH_CHECK(k >= 1 && k <= cand.size(1), "rerank_topk: need 1 <= k <= K, got k=", k, " K=", cand.size(1));
  const at::Tensor oc = own.contiguous(), tc = other.contiguous(), cc = cand.contiguous();
  const int64_t N = oc.size(0), M = tc.size(0), C = oc.size(1), K = cc.size(1);
  const float* po = oc.data_ptr<float>();
  const float* pt = tc.data_ptr<float>();
  const int64_t* pc = cc.data_ptr<int64_t>();
  for (int64_t q = 0; q < N * K; ++q) {
    TORCH_CHECK(pc[q] >= 0 && pc[q] < M, "rerank_topk: candidate index ", pc[q], " out of range [0, ", M,
                ") (a non-finite feature?)");
  }
  at::Tensor out = at::empty({N, k}, cc.options());
  int64_t* pout = out.data_ptr<int64_t>();
  abcgs::parallel_range(N, 64, [&](int64_t i0, int64_t i1) {
    std::vector<std::pair<float, int64_t>> scored(static_cast<size_t>(K));
    for (int64_t i = i0; i < i1; ++i) {
      const float* x = po + i * C;
      for (int64_t q = 0; q < K; ++q) {
        const int64_t j = pc[i * K + q];
        scored[q] = {row_dot(x, pt + j * C, C), j};
      }
      std::partial_sort(scored.begin(), scored.begin() + k, scored.end(), [](const auto& a, const auto& b) {
        return a.first > b.first || (a.first == b.first && a.second < b.second);
      });
      for (int64_t q = 0; q < k; ++q) pout[i * k + q] = scored[q].second;
    }
  });
  return out;
}
