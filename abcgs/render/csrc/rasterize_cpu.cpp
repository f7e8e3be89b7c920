// Fast CPU backend of the abcgs Gaussian rasterizer: tile binning, forward alpha blending and a
// hand-written backward pass, multi-threaded over 16x16 tiles on the kernels' own threads (parallel.h:
// set_kernel_threads, independent of torch's intra-op setting).
//
// The blending rule is the one in abcgs/render/reference.py (the test oracle):
//   sigma = 0.5 (a dx^2 + c dy^2) + b dx dy ; alpha = min(0.99, o exp(-sigma))
//   skip if sigma < 0 or alpha < 1/255 ; stop before T (1 - alpha) <= 1e-4 ;
//   C += c alpha T ; T *= 1 - alpha
//
// Determinism: each tile is processed by exactly one thread and writes only its own pixels and its
// own intersection rows; per-Gaussian gradients are then reduced over that Gaussian's intersections
// in a fixed order (tile-major, the binning order). Results do not depend on the thread count.
//
// Built with -ffp-contract=off so that the forward and backward passes evaluate alpha with the same
// rounding and therefore make the same skip/stop decisions.
//
// Layout of the work (docs/SCALING.md, "The tile rows in whole vectors"): a Gaussian's pixels in a tile are
// visited one 16-pixel tile row at a time, all its rows' alphas first (one vector each, their exp
// polynomials overlapping), then the rows with a nonzero lane are blended, or differentiated, in whole
// vectors (GCC/Clang vector extensions at the target's native width: 16 / 8 / 4 float lanes); the per-pixel
// state of a tile is kept by plane. The parameters a tile reads are packed in depth order (GaussianView), so a tile's list
// walks one array forwards.

#include "torch_api.h"

#include "fast_exp.h"
#include "parallel.h"
#include "thresholds.h"
#include "vec_width.h"

#if defined(__AVX2__) || defined(__AVX512F__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <optional>
#include <type_traits>
#include <vector>

namespace {

constexpr double kMaxAlpha = 0.99;
constexpr double kTransmittanceEps = 1e-4;

// Tile lists and, for the backward pass, where each intersection's gradient row goes (grouped by Gaussian), stored
// in tensors so the forward pass can hand them to autograd for the backward pass without copies.
struct Binning {
  int64_t tiles_x = 0, tiles_y = 0;
  at::Tensor tile_offsets_t, slots_t, order_t, slot_offsets_t, isect_rows_t;
  const int64_t* tile_offsets = nullptr;  // (n_tiles + 1) start of each tile's list in `slots`
  const int32_t* slots = nullptr;         // (M) depth rank of each intersection's Gaussian (its index in
                                          //     `order`), increasing along a tile's list; order[slots] = ids
  const int32_t* order = nullptr;         // (V) the Gaussians with a positive extent, front to back
  const int64_t* slot_offsets = nullptr;  // (V + 1) start of each slot's gradient rows (slot-major, tile order)
  const int64_t* isect_rows = nullptr;    // (M) the slot-major gradient row of each intersection (tile-major)
  int64_t num_isects() const { return slots_t.numel(); }
  int64_t num_slots() const { return order_t.numel(); }

  Binning(at::Tensor tile_offsets_, at::Tensor slots_, at::Tensor order_, at::Tensor slot_offsets_,
          at::Tensor isect_rows_, int64_t width, int64_t height, int64_t tile)
      : tiles_x((width + tile - 1) / tile),
        tiles_y((height + tile - 1) / tile),
        tile_offsets_t(tile_offsets_.contiguous()),
        slots_t(slots_.contiguous()),
        order_t(order_.contiguous()),
        slot_offsets_t(slot_offsets_.contiguous()),
        isect_rows_t(isect_rows_.contiguous()) {
    TORCH_CHECK(tile_offsets_t.numel() == tiles_x * tiles_y + 1, "binning does not match the image size");
    TORCH_CHECK(slot_offsets_t.numel() == order_t.numel() + 1 && isect_rows_t.numel() == slots_t.numel(),
                "binning: slot offsets or intersection rows do not match");
    tile_offsets = tile_offsets_t.data_ptr<int64_t>();
    slots = slots_t.data_ptr<int32_t>();
    order = order_t.data_ptr<int32_t>();
    slot_offsets = slot_offsets_t.data_ptr<int64_t>();
    isect_rows = isect_rows_t.data_ptr<int64_t>();
  }
};

// Front-to-back order of the Gaussians with a positive extent: a stable LSD radix sort (8-bit digits) of
// the depth bits mapped to order-preserving unsigned keys. Ties keep index order and NaN depths go last,
// i.e. the same permutation as `torch.argsort(depths[extents[:, 0] > 0], stable=True)` (one exception: -0.0
// sorts before +0.0, which torch treats as a tie; projected Gaussians have depth > near > 0).
template <typename scalar_t>
at::Tensor depth_order(const scalar_t* depth, const scalar_t* ext, int64_t n) {
  using key_t = std::conditional_t<sizeof(scalar_t) == 4, uint32_t, uint64_t>;
  constexpr key_t kSign = key_t(1) << (8 * sizeof(key_t) - 1);
  TORCH_CHECK(n < (int64_t(1) << 31), "abcgs cpu rasterizer: at most 2^31 - 1 Gaussians");
  // the kept Gaussians in index order, with their keys
  std::vector<key_t> keys, keys_tmp;
  std::vector<int32_t> idx, idx_tmp;
  const int64_t m = abcgs::parallel_compact(
      n, [&](int64_t g) { return ext[2 * g] > 0; },
      [&](int64_t count) {
        keys.resize(count), keys_tmp.resize(count), idx.resize(count), idx_tmp.resize(count);
      },
      [&](int64_t g, int64_t j) {
        const scalar_t d = depth[g];
        key_t k = ~key_t(0);
        if (!std::isnan(d)) {
          std::memcpy(&k, &d, sizeof(k));
          k = (k & kSign) ? ~k : (k | kSign);
        }
        keys[j] = k;
        idx[j] = static_cast<int32_t>(g);
      });
  // each pass: the workers count their own contiguous ranges, then scatter them to (digit, worker) offsets, so
  // that equal digits keep their order (stable) and the permutation does not depend on the worker count
  const int64_t rw = std::max<int64_t>(1, std::min<int64_t>(abcgs::kernel_threads(), (m + 65535) / 65536));
  const int64_t rchunk = (m + rw - 1) / rw;
  std::vector<int64_t> hist(rw * 256);
  for (int shift = 0; shift < static_cast<int>(8 * sizeof(key_t)); shift += 8) {
    std::fill(hist.begin(), hist.end(), 0);
    abcgs::run_workers(rw, [&](int64_t w) {
      int64_t* h = &hist[w * 256];
      for (int64_t i = w * rchunk, e = std::min(m, (w + 1) * rchunk); i < e; ++i) h[(keys[i] >> shift) & 0xff]++;
    });
    bool one_bucket = false;  // every key has the same digit: order unchanged
    int64_t pos = 0;
    for (int b = 0; b < 256; ++b) {
      int64_t total = 0;
      for (int64_t w = 0; w < rw; ++w) {
        const int64_t c = hist[w * 256 + b];
        hist[w * 256 + b] = pos;
        pos += c;
        total += c;
      }
      one_bucket |= total == m;
    }
    if (one_bucket) continue;
    abcgs::run_workers(rw, [&](int64_t w) {
      int64_t* h = &hist[w * 256];
      for (int64_t i = w * rchunk, e = std::min(m, (w + 1) * rchunk); i < e; ++i) {
        const int64_t to = h[(keys[i] >> shift) & 0xff]++;
        keys_tmp[to] = keys[i];
        idx_tmp[to] = idx[i];
      }
    });
    keys.swap(keys_tmp);
    idx.swap(idx_tmp);
  }
  at::Tensor order = at::empty({m}, at::kInt);
  std::copy(idx.begin(), idx.end(), order.data_ptr<int32_t>());
  return order;
}

// Inclusive tile box (tx0, ty0, tx1, ty1) of a Gaussian's pixel box `mean ± ext`: the tiles whose pixel
// centres (x + 0.5) it overlaps. Same arithmetic as `tile_ranges` in abcgs/render/reference.py; returns
// false for an empty box (no pixel centre inside, zero or non-finite extent).
template <typename scalar_t>
inline bool tile_box(scalar_t mx, scalar_t my, scalar_t ex, scalar_t ey, int64_t width, int64_t height, int64_t tile,
                     int32_t box[4]) {
  const scalar_t h = scalar_t(0.5);
  if (!(ex > 0) || !std::isfinite(mx) || !std::isfinite(my) || !std::isfinite(ex) || !std::isfinite(ey)) return false;
  const scalar_t wmax = scalar_t(width - 1), hmax = scalar_t(height - 1), zero = scalar_t(0);
  const scalar_t x0 = std::min(std::max(std::ceil(mx - ex - h), zero), wmax);
  const scalar_t x1 = std::min(std::max(std::floor(mx + ex - h), zero), wmax);
  const scalar_t y0 = std::min(std::max(std::ceil(my - ey - h), zero), hmax);
  const scalar_t y1 = std::min(std::max(std::floor(my + ey - h), zero), hmax);
  if (mx + ex - h < x0 || my + ey - h < y0 || mx - ex - h > x1 || my - ey - h > y1) return false;
  box[0] = static_cast<int32_t>(static_cast<int64_t>(x0) / tile);
  box[1] = static_cast<int32_t>(static_cast<int64_t>(y0) / tile);
  box[2] = static_cast<int32_t>(static_cast<int64_t>(x1) / tile);
  box[3] = static_cast<int32_t>(static_cast<int64_t>(y1) / tile);
  return true;
}

// Run `fn(tile)` for every tile with dynamic scheduling on the kernels' threads (parallel.h).
template <typename F>
void for_each_tile(int64_t n_tiles, const F& fn) {
  abcgs::parallel_items(n_tiles, fn);
}

// Pixel-column range [x_lo, x_hi) of a Gaussian's box inside one tile (same for rows).
template <typename scalar_t>
inline void box_in_tile(scalar_t mean, scalar_t ext, int64_t lo, int64_t hi, int64_t& a, int64_t& b) {
  a = std::max<int64_t>(lo, static_cast<int64_t>(std::ceil(mean - ext - scalar_t(0.5))));
  b = std::min<int64_t>(hi, static_cast<int64_t>(std::floor(mean + ext - scalar_t(0.5))) + 1);
}

// Forward and backward share exp_fast, so their skip/stop decisions agree exactly. Doubles use std::exp (exact
// gradient checks).
inline float exp_neg(float s) { return abcgs::exp_fast(-s); }
inline double exp_neg(double s) { return std::exp(-s); }

// Pixels per call of row_alpha: one AVX-512 vector (two AVX2 vectors) of float, a whole row of a 16 x 16 tile.
// A Gaussian covers typically 2-8 pixels of a tile row; evaluating the whole row branch-free and then using
// only its nonzero lanes costs less than first narrowing each row to the ellipse's span (a double-precision
// square root and two divides per row, which this replaced).
constexpr int64_t kRowChunk = 16;
// Rows of one Gaussian evaluated together (the height of a 16 x 16 tile).
constexpr int64_t kRowBatch = 16;
// Float lanes of one native vector (vec_width.h): a row chunk is kRowChunk / kPartLanes of them ("parts"). A part
// with no lane inside the Gaussian's box is neither evaluated nor blended: a Gaussian covers 8 pixels of a tile row
// on average, so on AVX2 one of a row's two parts is often empty.
constexpr int64_t kPartLanes = ABCGS_VEC_BYTES / 4 < kRowChunk ? ABCGS_VEC_BYTES / 4 : kRowChunk;
static_assert(kRowChunk % kPartLanes == 0, "a row chunk must be whole parts");
// The lane bits of part q (starting at lane q0 = q * kPartLanes) in a lane mask of a row chunk.
inline uint32_t part_bits(uint32_t mask, int64_t q0) {
  return (mask >> q0) & static_cast<uint32_t>((uint64_t(1) << kPartLanes) - 1);
}

// Alpha (0 where skipped: sigma < 0 or alpha < 1/255, and outside lanes [lo, hi)) and exp(-sigma) for the
// kRowChunk pixels x = xc + i (i < kRowChunk) of one row at offset dy from the mean: the branch-free part of
// blending. dx is formed as (xc + 0.5 - mx) + i. Only the parts with a lane in `eval` (a lane mask inside
// [lo, hi)) are evaluated; the others get alpha 0 and exp 0.
template <typename scalar_t>
inline void row_alpha(int64_t xc, int32_t lo, int32_t hi, uint32_t eval, scalar_t mx, scalar_t dy, scalar_t ca,
                      scalar_t cb, scalar_t cc, scalar_t o, scalar_t* __restrict alpha, scalar_t* __restrict vis) {
  const scalar_t half_cdy2 = scalar_t(0.5) * cc * dy * dy, cbdy = cb * dy;
  const scalar_t x0 = scalar_t(xc) + scalar_t(0.5) - mx;
  for (int32_t q0 = 0; q0 < int32_t(kRowChunk); q0 += int32_t(kPartLanes)) {
    if (part_bits(eval, q0) == 0) {  // no lane to evaluate in this part: alpha 0
      std::fill(alpha + q0, alpha + q0 + kPartLanes, scalar_t(0));
      std::fill(vis + q0, vis + q0 + kPartLanes, scalar_t(0));
      continue;
    }
    for (int32_t i = q0; i < q0 + int32_t(kPartLanes); ++i) {
      const scalar_t dx = x0 + scalar_t(i);
      const scalar_t sigma = scalar_t(0.5) * ca * dx * dx + half_cdy2 + cbdy * dx;
      const scalar_t e = exp_neg(sigma);
      const scalar_t a = std::min(scalar_t(kMaxAlpha), o * e);
      const scalar_t a_kept = a >= scalar_t(kAlphaThreshold) ? a : scalar_t(0);  // selects, not a bool mask:
      const scalar_t a_row = sigma >= scalar_t(0) ? a_kept : scalar_t(0);       // GCC vectorises these
      alpha[i] = (i >= lo && i < hi) ? a_row : scalar_t(0);
      vis[i] = e;
    }
  }
}

// Bit i set when lane i of a kRowChunk buffer (64-byte aligned) is not 0.
template <typename scalar_t>
inline uint32_t nonzero_lanes(const scalar_t* v) {
  uint32_t mask = 0;
  for (int64_t i = 0; i < kRowChunk; ++i) mask |= (v[i] != scalar_t(0) ? 1u : 0u) << i;
  return mask;
}
template <>
inline uint32_t nonzero_lanes<float>(const float* v) {
  static_assert(kRowChunk == 16, "the vector paths below test 16 float lanes");
#if defined(__AVX512F__)
  return static_cast<uint32_t>(_mm512_cmp_ps_mask(_mm512_load_ps(v), _mm512_setzero_ps(), _CMP_NEQ_UQ));
#elif defined(__AVX2__)
  const __m256 zero = _mm256_setzero_ps();
  const uint32_t lo = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps(_mm256_load_ps(v), zero, _CMP_NEQ_UQ)));
  const uint32_t hi = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps(_mm256_load_ps(v + 8), zero, _CMP_NEQ_UQ)));
  return lo | (hi << 8);
#else
  uint32_t mask = 0;
  for (int64_t i = 0; i < kRowChunk; ++i) mask |= (v[i] != 0.0f ? 1u : 0u) << i;
  return mask;
#endif
}

// The visible Gaussians' parameters packed in depth order (slot = depth rank), so that a tile's list, a
// subsequence of that order, reads them at increasing addresses from one array instead of gathering from
// five tensors by Gaussian index (a cache miss per intersection on a real scene: docs/SCALING.md). The forward
// pass packs them once and hands the two tensors to the backward pass.
template <typename scalar_t>
struct GaussianView {
  static constexpr int64_t kStride = 8;  // mean x, mean y, conic a, b, c, opacity, extent x, extent y
  at::Tensor params_t, colors_t;         // (V, kStride), (V, C)
  const scalar_t* params = nullptr;
  const scalar_t* colors = nullptr;
  int64_t channels = 0;

  // the Gaussians of `order` (V,) int32 (depth order) among n, packed at their slots; with `extra` (N,), its value
  // is the last of the C + 1 channels (RGB+D: the depths, with no (N, C + 1) copy). The sources are read in index
  // order (streamed) and each slot written once: gathering them in depth order instead missed the cache on each of
  // the five source arrays per Gaussian (twice the time on 3 M Gaussians).
  GaussianView(const scalar_t* means2d, const scalar_t* conics, const scalar_t* colors_, const scalar_t* opac,
               const scalar_t* extents, int64_t C, int64_t n, const at::Tensor& order, const at::TensorOptions& opts,
               const scalar_t* extra = nullptr)
      : params_t(at::empty({order.numel(), kStride}, opts)),
        colors_t(at::empty({order.numel(), C + (extra != nullptr)}, opts)),
        channels(C + (extra != nullptr)) {
    const int64_t CT = channels;
    scalar_t* pp = params_t.data_ptr<scalar_t>();
    scalar_t* cp = colors_t.data_ptr<scalar_t>();
    const int32_t* od = order.data_ptr<int32_t>();
    const int64_t v = order.numel();
    std::vector<int32_t> slot_of(static_cast<size_t>(n), -1);
    abcgs::parallel_range(v, 65536, [&](int64_t begin, int64_t end) {
      for (int64_t s = begin; s < end; ++s) slot_of[od[s]] = static_cast<int32_t>(s);
    });
    abcgs::parallel_range(n, 65536, [&](int64_t begin, int64_t end) {
      for (int64_t g = begin; g < end; ++g) {
        const int64_t s = slot_of[g];
        if (s < 0) continue;
        scalar_t* p = pp + s * kStride;
        p[0] = means2d[2 * g];
        p[1] = means2d[2 * g + 1];
        p[2] = conics[3 * g];
        p[3] = conics[3 * g + 1];
        p[4] = conics[3 * g + 2];
        p[5] = opac[g];
        p[6] = extents[2 * g];
        p[7] = extents[2 * g + 1];
        std::copy(colors_ + g * C, colors_ + (g + 1) * C, cp + s * CT);
        if (extra != nullptr) cp[s * CT + C] = extra[g];
      }
    });
    params = pp;
    colors = cp;
  }
  // the forward pass's packing, read back
  GaussianView(const at::Tensor& params_, const at::Tensor& colors_, const Binning& bin)
      : params_t(params_.contiguous()), colors_t(colors_.contiguous()), channels(colors_.size(1)) {
    TORCH_CHECK(params_t.size(0) == bin.num_slots() && params_t.size(1) == kStride &&
                    colors_t.size(0) == bin.num_slots(), "rasterize_backward: the packed Gaussians do not match the binning");
    params = params_t.data_ptr<scalar_t>();
    colors = colors_t.data_ptr<scalar_t>();
  }
  const scalar_t* at(int64_t slot) const { return params + slot * kStride; }
  const scalar_t* color(int64_t slot) const { return colors + slot * channels; }
  // a tile's list jumps through the packed arrays: ask for the entry a few places ahead early
  void prefetch(int64_t slot) const {
    __builtin_prefetch(params + slot * kStride);
    __builtin_prefetch(colors + slot * channels);
  }
};

// How far ahead along a tile's list the parameters are prefetched.
constexpr int64_t kPrefetchAhead = 8;

// Bin the packed Gaussians (slot = depth rank) into tiles (see `tile_box`): each tile's list in depth order, and
// each slot's gradient rows together (slot-major, the slot's tiles in row order) so that the backward pass sums
// a Gaussian's rows from one place. The boxes come from the packed view, read in slot order.
template <typename scalar_t>
Binning bin_tiles(const GaussianView<scalar_t>& gv, const at::Tensor& order, int64_t width, int64_t height,
                  int64_t tile) {
  const int64_t tiles_x = (width + tile - 1) / tile, tiles_y = (height + tile - 1) / tile;
  const int64_t n_tiles = tiles_x * tiles_y, n_vis = order.numel();
  at::Tensor slot_offsets = at::empty({n_vis + 1}, at::kLong);
  int64_t* soff = slot_offsets.data_ptr<int64_t>();
  std::vector<int32_t> boxes(4 * n_vis);
  abcgs::parallel_range(n_vis, 16384, [&](int64_t begin, int64_t end) {
    for (int64_t k = begin; k < end; ++k) {
      const scalar_t* p = gv.at(k);
      int32_t* r = &boxes[4 * k];
      const bool hit = tile_box(p[0], p[1], p[6], p[7], width, height, tile, r);
      soff[k + 1] = hit ? int64_t(r[2] - r[0] + 1) * (r[3] - r[1] + 1) : 0;
    }
  });
  soff[0] = 0;
  for (int64_t k = 0; k < n_vis; ++k) soff[k + 1] += soff[k];
  const int64_t m = soff[n_vis];
  // Each worker counts the tiles of its own contiguous range of slots, then writes its entries at its offset
  // inside each tile (the workers' ranges in slot order): every tile's list is in slot order, whatever the
  // worker count.
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(abcgs::kernel_threads(), (n_vis + 65535) / 65536));
  const int64_t chunk = (n_vis + workers - 1) / workers;
  std::vector<int64_t> cursor(workers * n_tiles, 0);
  abcgs::run_workers(workers, [&](int64_t w) {
    int64_t* count = &cursor[w * n_tiles];
    for (int64_t k = w * chunk, e = std::min(n_vis, (w + 1) * chunk); k < e; ++k) {
      if (soff[k + 1] == soff[k]) continue;
      const int32_t* r = &boxes[4 * k];
      for (int64_t ty = r[1]; ty <= r[3]; ++ty)
        for (int64_t tx = r[0]; tx <= r[2]; ++tx) count[ty * tiles_x + tx]++;
    }
  });
  at::Tensor tile_offsets = at::empty({n_tiles + 1}, at::kLong);
  int64_t* toff = tile_offsets.data_ptr<int64_t>();
  toff[0] = 0;
  for (int64_t t = 0; t < n_tiles; ++t) {
    int64_t pos = toff[t];
    for (int64_t w = 0; w < workers; ++w) {
      const int64_t c = cursor[w * n_tiles + t];
      cursor[w * n_tiles + t] = pos;
      pos += c;
    }
    toff[t + 1] = pos;
  }
  at::Tensor slots = at::empty({m}, at::kInt);
  at::Tensor isect_rows = at::empty({m}, at::kLong);
  int32_t* sl = slots.data_ptr<int32_t>();
  int64_t* ir = isect_rows.data_ptr<int64_t>();
  abcgs::run_workers(workers, [&](int64_t w) {
    int64_t* cur = &cursor[w * n_tiles];
    for (int64_t k = w * chunk, e = std::min(n_vis, (w + 1) * chunk); k < e; ++k) {
      const int32_t* r = &boxes[4 * k];
      int64_t j = soff[k];
      if (j == soff[k + 1]) continue;
      for (int64_t ty = r[1]; ty <= r[3]; ++ty)
        for (int64_t tx = r[0]; tx <= r[2]; ++tx) {
          const int64_t pos = cur[ty * tiles_x + tx]++;
          sl[pos] = static_cast<int32_t>(k);
          ir[pos] = j++;
        }
    }
  });
  return Binning(tile_offsets, slots, order, slot_offsets, isect_rows, width, height, tile);
}

// Bit i set when v[i] > k, for the kRowChunk consecutive values at v (any alignment).
inline uint32_t lanes_above(const int32_t* v, int32_t k) {
  static_assert(kRowChunk == 16, "the vector paths below test 16 int32 lanes");
#if defined(__AVX512F__)
  return static_cast<uint32_t>(_mm512_cmpgt_epi32_mask(_mm512_loadu_si512(v), _mm512_set1_epi32(k)));
#elif defined(__AVX2__)
  const __m256i kv = _mm256_set1_epi32(k);
  const __m256i a = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(v));
  const __m256i b = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(v + 8));
  const uint32_t lo = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(a, kv))));
  const uint32_t hi = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(b, kv))));
  return lo | (hi << 8);
#else
  uint32_t mask = 0;
  for (int64_t i = 0; i < kRowChunk; ++i) mask |= (v[i] > k ? 1u : 0u) << i;
  return mask;
#endif
}

// Lanes [lo, hi) of a row chunk as a bit mask (0 <= lo <= hi <= kRowChunk).
inline uint32_t lane_range(int32_t lo, int32_t hi) {
  return static_cast<uint32_t>(((uint64_t(1) << hi) - 1) & ~((uint64_t(1) << lo) - 1));
}

// Every lane may still change (the `live` test of a caller that tracks no per-pixel state).
struct AllLanes {
  uint32_t operator()(int64_t) const { return ~0u; }
};

// Visit, row by row, where Gaussian g reaches alpha >= 1/255 (and sigma >= 0) in the tile [x0, x1) x [y0, y1):
// the rows of its box inside the tile, each in chunks of kRowChunk pixels aligned to the tile's left edge.
// A chunk's alpha (0 = skipped, and 0 outside the box) and exp(-sigma) are computed in one vectorised pass,
// kRowBatch rows before their pixels are used: the rows' exp polynomials are independent, so the core overlaps
// them instead of waiting out one row's dependency chain at a time (docs/SCALING.md, "The tile rows").
// fn(p0, xc, dy, mask, alpha, vis, inv) gets the tile-local index p0 of the chunk's first pixel (column xc),
// the bit mask of its lanes with a nonzero alpha (never 0), and kRowChunk-lane buffers; inv = 1 / (1 - alpha)
// when kInverse (the backward pass: one vector divide per chunk, correctly rounded like a scalar one), else
// unset. Lanes past the tile's right edge have alpha 0.
// live(p0) gives the lanes of the chunk at tile-local index p0 whose pixel the Gaussian can still change (the
// forward pass: not done; the backward pass: blended after this entry). A row with no live lane in the box is
// skipped before its alphas are computed, and a vector part with none is not evaluated: a pixel that cannot
// change ignores its lane, so the results are those of evaluating every lane.
template <bool kInverse, typename scalar_t, typename L, typename F>
inline void for_each_covered_row(const GaussianView<scalar_t>& gv, int64_t slot, int64_t x0, int64_t x1, int64_t y0,
                                 int64_t y1, int64_t tw, const L& live, F&& fn) {
  alignas(64) scalar_t abuf[kRowBatch][kRowChunk], ebuf[kRowBatch][kRowChunk], rbuf[kRowChunk];
  uint32_t masks[kRowBatch];
  const scalar_t* gp = gv.at(slot);
  const scalar_t mx = gp[0], my = gp[1], ca = gp[2], cb = gp[3], cc = gp[4], o = gp[5];
  int64_t xa, xb, ya, yb;
  box_in_tile<scalar_t>(mx, gp[6], x0, x1, xa, xb);
  box_in_tile<scalar_t>(my, gp[7], y0, y1, ya, yb);
  if (xa >= xb) return;
  for (int64_t xc = x0 + (xa - x0) / kRowChunk * kRowChunk; xc < xb; xc += kRowChunk) {
    const int32_t lo = static_cast<int32_t>(std::max<int64_t>(xa - xc, 0));  // the box's lanes
    const int32_t hi = static_cast<int32_t>(std::min<int64_t>(xb - xc, kRowChunk));
    const uint32_t box = lane_range(lo, hi);
    for (int64_t yr = ya; yr < yb; yr += kRowBatch) {
      const int64_t nr = std::min<int64_t>(kRowBatch, yb - yr);
      uint32_t any = 0;
      for (int64_t r = 0; r < nr; ++r) {
        const uint32_t eval = box & live((yr + r - y0) * tw + (xc - x0));
        if (eval == 0) {
          masks[r] = 0;
          continue;
        }
        const scalar_t dy = scalar_t(yr + r) + scalar_t(0.5) - my;
        scalar_t* a = abuf[r];
        row_alpha<scalar_t>(xc, lo, hi, eval, mx, dy, ca, cb, cc, o, a, ebuf[r]);
        masks[r] = nonzero_lanes(a);
        any |= masks[r];
      }
      if (any == 0) continue;
      for (int64_t r = 0; r < nr; ++r) {
        if (masks[r] == 0) continue;
        const int64_t y = yr + r;
        const scalar_t dy = scalar_t(y) + scalar_t(0.5) - my;
        if constexpr (kInverse) {
          for (int64_t i = 0; i < kRowChunk; ++i) rbuf[i] = scalar_t(1) / (scalar_t(1) - abuf[r][i]);
        }
        fn((y - y0) * tw + (xc - x0), xc, dy, masks[r], static_cast<const scalar_t*>(abuf[r]),
           static_cast<const scalar_t*>(ebuf[r]), static_cast<const scalar_t*>(rbuf));
      }
    }
  }
}

// GCC/Clang vector extensions at the target's native width (vec_width.h); a kRowChunk-pixel chunk is kParts of them.
typedef float f32v __attribute__((vector_size(ABCGS_VEC_BYTES)));
typedef int32_t i32v __attribute__((vector_size(ABCGS_VEC_BYTES)));
constexpr int64_t kLanes = ABCGS_VEC_BYTES / 4;
constexpr int64_t kParts = kRowChunk / kLanes;
static_assert(kParts * kLanes == kRowChunk && kLanes == kPartLanes, "a row chunk must be whole vectors");

template <typename V>
inline V load_v(const void* p) {
  V v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
template <typename V>
inline void store_v(void* p, const V& v) {
  std::memcpy(p, &v, sizeof(v));
}

// Front-to-back blend of one Gaussian into one chunk of 16 pixels (float): lanes with alpha 0 (skipped, outside
// the box or the tile), a done pixel, or a blend that would take T to the stop threshold keep their values;
// the last marks its pixel done. The same operations, in the same order per pixel, as blending one pixel at a
// time. T, done, last and the colour planes (acc + c * stride) are read and written at 16 consecutive lanes.
// Returns how many pixels stopped; sets `blended` when a lane blended.
template <int64_t kChannels>
inline int64_t blend_chunk_f32(const float* alpha, uint32_t mask, float* T, int32_t* done, int32_t* last, float* acc,
                               int64_t stride, int64_t channels, const float* col, int32_t order, bool& blended) {
  const int64_t C = kChannels > 0 ? kChannels : channels;
  const i32v zero_i = {};
  const f32v zero_f = {};
  const i32v one_i = zero_i + 1, order_i = zero_i + order;
  const f32v one_f = zero_f + 1.0f;
  alignas(64) float stop_lanes[kRowChunk], blend_lanes[kRowChunk];
  for (int64_t q = 0; q < kParts; ++q) {
    const int64_t off = q * kLanes;
    if (part_bits(mask, off) == 0) {  // every alpha 0: nothing changes
      store_v(stop_lanes + off, zero_f);
      store_v(blend_lanes + off, zero_f);
      continue;
    }
    const f32v a = load_v<f32v>(alpha + off);
    f32v t = load_v<f32v>(T + off);
    i32v d = load_v<i32v>(done + off), l = load_v<i32v>(last + off);
    const f32v next_t = t * (1.0f - a);
    const i32v live = (a != 0.0f) & (d == 0);
    const i32v stop = live & (next_t <= static_cast<float>(kTransmittanceEps));
    const i32v blend = live & ~stop;
    d = stop ? one_i : d;
    l = blend ? order_i : l;
    const f32v w = a * t;
    t = blend ? next_t : t;
    store_v(T + off, t);
    store_v(done + off, d);
    store_v(last + off, l);
    for (int64_t c = 0; c < C; ++c) {
      f32v v = load_v<f32v>(acc + c * stride + off);
      v = blend ? v + w * col[c] : v;
      store_v(acc + c * stride + off, v);
    }
    store_v(stop_lanes + off, f32v(stop ? one_f : zero_f));
    store_v(blend_lanes + off, f32v(blend ? one_f : zero_f));
  }
  blended |= nonzero_lanes(blend_lanes) != 0;
  return __builtin_popcount(nonzero_lanes(stop_lanes));
}

// Forward pass for one tile. Writes image (H, W, C), transmittance (H, W), per pixel the number of tile-list
// entries up to and including the last Gaussian blended (0 = none), and per intersection whether its Gaussian
// blended any pixel of the tile (`blended`, the backward pass skips the others: their gradient is 0).
template <typename scalar_t, int64_t kChannels>
void forward_tile(const GaussianView<scalar_t>& gv, const Binning& bin, int64_t tile, int64_t width, int64_t height,
                  int64_t tile_size, scalar_t* image, scalar_t* trans, int32_t* last, uint8_t* blended) {
  const int64_t C = kChannels > 0 ? kChannels : gv.channels;
  const int64_t tx = tile % bin.tiles_x, ty = tile / bin.tiles_x;
  const int64_t x0 = tx * tile_size, y0 = ty * tile_size;
  const int64_t x1 = std::min(width, x0 + tile_size), y1 = std::min(height, y0 + tile_size);
  const int64_t tw = x1 - x0, th = y1 - y0, npix = tw * th;
  // Per-pixel state by channel plane (acc[c * stride + p]) with kRowChunk lanes of padding, so that a row chunk
  // reads and writes 16 consecutive values. A chunk is blended in whole vectors: a lane blends when its alpha
  // is not 0, its pixel is not done and the blend keeps T above the stop threshold; the other lanes keep their
  // values (selects, not arithmetic with zeros). Each pixel sees the operations of a one-pixel-at-a-time blend
  // in the same order, so results do not change.
  const int64_t stride = npix + kRowChunk;
  std::vector<scalar_t> T(stride, scalar_t(1)), acc(stride * C, scalar_t(0));
  std::vector<int32_t> lst(stride, 0), done(stride, 0);
  int64_t remaining = npix;
  const int64_t start = bin.tile_offsets[tile], end = bin.tile_offsets[tile + 1];
  for (int64_t k = start; k < end && remaining > 0; ++k) {
    if (k + kPrefetchAhead < end) gv.prefetch(bin.slots[k + kPrefetchAhead]);
    const int64_t slot = bin.slots[k];
    const scalar_t* colp = gv.color(slot);
    // a local copy: the compiler cannot know that the blend's stores to `acc` leave the colours alone
    scalar_t col[kChannels > 0 ? kChannels : 1];
    if constexpr (kChannels > 0) std::copy(colp, colp + C, col);
    const int32_t order = static_cast<int32_t>(k - start + 1);
    bool any = false;
    const int32_t* done_p = done.data();
    for_each_covered_row<false>(gv, slot, x0, x1, y0, y1, tw,
                                [done_p](int64_t p0) { return ~lanes_above(done_p + p0, 0); },
                                [&](int64_t p0, int64_t, scalar_t, uint32_t mask, const scalar_t* __restrict alpha,
                                    const scalar_t*, const scalar_t*) {
      if constexpr (std::is_same_v<scalar_t, float>) {
        remaining -= blend_chunk_f32<kChannels>(alpha, mask, T.data() + p0, done.data() + p0, lst.data() + p0,
                                                acc.data() + p0, stride, C, kChannels > 0 ? col : colp, order, any);
      } else {
        for (int64_t i = 0; i < kRowChunk; ++i) {
          const int64_t p = p0 + i;
          const scalar_t a = alpha[i];
          if (a == scalar_t(0) || done[p]) continue;
          const scalar_t next_T = T[p] * (scalar_t(1) - a);
          if (next_T <= scalar_t(kTransmittanceEps)) {
            done[p] = 1;
            --remaining;
            continue;
          }
          const scalar_t w = a * T[p];
          for (int64_t c = 0; c < C; ++c) acc[c * stride + p] += w * colp[c];
          T[p] = next_T;
          lst[p] = order;
          any = true;
        }
      }
    });
    blended[k] = any;
  }
  for (int64_t y = y0; y < y1; ++y)
    for (int64_t x = x0; x < x1; ++x) {
      const int64_t p = (y - y0) * tw + (x - x0), q = y * width + x;
      trans[q] = T[p];
      last[q] = lst[p];
      for (int64_t c = 0; c < C; ++c) image[q * C + c] = acc[c * stride + p];
    }
}

// Sum of a chunk's lanes (kParts vectors), in a fixed order (pairwise halves: x[i] += x[i + h] for h = 8, 4, 2, 1).
// The AVX2 path adds the same pairs with vector instructions, so it gives the same bits as the scalar loop.
__attribute__((always_inline)) inline float sum_lanes(const f32v (&v)[kParts]) {
#if defined(__AVX2__) && !defined(__AVX512F__)
  static_assert(kParts == 2 && kLanes == 8, "AVX2: a chunk is two vectors of eight lanes");
  __m256 x = _mm256_add_ps(reinterpret_cast<__m256>(v[0]), reinterpret_cast<__m256>(v[1]));  // h = 8
  __m128 y = _mm_add_ps(_mm256_castps256_ps128(x), _mm256_extractf128_ps(x, 1));             // h = 4
  y = _mm_add_ps(y, _mm_movehl_ps(y, y));                                                     // h = 2
  y = _mm_add_ss(y, _mm_shuffle_ps(y, y, 1));                                                 // h = 1
  return _mm_cvtss_f32(y);
#else
  alignas(64) float x[kRowChunk];
  for (int64_t q = 0; q < kParts; ++q) store_v(x + q * kLanes, v[q]);
  for (int64_t h = kRowChunk / 2; h > 0; h /= 2)
    for (int64_t i = 0; i < h; ++i) x[i] += x[i + h];
  return x[0];
#endif
}

// Backward pass for one tile: walks the tile's list back to front, reconstructing each pixel's
// transmittance from its final value, and writes one gradient row per intersection:
// [d mean_x, d mean_y, d conic_a, d conic_b, d conic_c, d opacity, d color_0 .. d color_{C-1}].
//
// Per-pixel state by plane with kRowChunk lanes of padding (as in forward_tile). For float and a compile-time
// channel count a row chunk is processed in whole vectors: lanes with alpha 0 or past their pixel's last
// blended Gaussian are inactive (selects keep their state and add nothing), and the Gaussian's gradient is
// summed per lane over its rows, then over the lanes (sum_lanes). Other cases visit the active pixels one by
// one, left to right.
template <typename scalar_t, int64_t kChannels>
void backward_tile(const GaussianView<scalar_t>& gv, const Binning& bin, int64_t tile, int64_t width,
                   int64_t height, int64_t tile_size, const scalar_t* trans, const int32_t* last,
                   const scalar_t* v_image, const scalar_t* v_alpha, const uint8_t* blended,
                   scalar_t* isect_grads, uint8_t* row_written) {
  constexpr bool kVector = std::is_same_v<scalar_t, float> && kChannels > 0;
  const int64_t C = kChannels > 0 ? kChannels : gv.channels, row = 6 + C;
  const int64_t tx = tile % bin.tiles_x, ty = tile / bin.tiles_x;
  const int64_t x0 = tx * tile_size, y0 = ty * tile_size;
  const int64_t x1 = std::min(width, x0 + tile_size), y1 = std::min(height, y0 + tile_size);
  const int64_t tw = x1 - x0, th = y1 - y0, npix = tw * th, stride = npix + kRowChunk;
  const int64_t start = bin.tile_offsets[tile];
  // TfvA = T_final * dL/d alpha_pixel: d alpha_pixel / d alpha_i = T_final / (1 - alpha_i)
  std::vector<scalar_t> T(stride, scalar_t(1)), TfvA(stride, scalar_t(0)), S(stride * C, scalar_t(0)),
      vimg(stride * C, scalar_t(0));
  std::vector<int32_t> lst(stride, 0);
  int32_t max_last = 0;
  for (int64_t y = y0; y < y1; ++y)
    for (int64_t x = x0; x < x1; ++x) {
      const int64_t p = (y - y0) * tw + (x - x0), q = y * width + x;
      T[p] = trans[q];
      TfvA[p] = v_alpha[q] * trans[q];
      lst[p] = last[q];
      max_last = std::max(max_last, last[q]);
      for (int64_t c = 0; c < C; ++c) vimg[c * stride + p] = v_image[q * C + c];
    }
  constexpr int64_t kCols = kChannels > 0 ? kChannels : 1;
  std::vector<scalar_t> gcol_heap(kChannels > 0 ? 0 : C);
  scalar_t gcol_fixed[kCols];
  scalar_t* gcol = kChannels > 0 ? gcol_fixed : gcol_heap.data();
  // Only the rows of entries that blended a pixel are written, and flagged in `row_written`: the others (past
  // the last Gaussian any pixel blended, or blending none of the tile's pixels) have gradient 0, and the
  // reduction skips them instead of summing zeros.
  for (int64_t kk = max_last - 1; kk >= 0; --kk) {
    const int64_t k = start + kk;
    if (kk >= kPrefetchAhead) gv.prefetch(bin.slots[k - kPrefetchAhead]);
    if (!blended[k]) continue;
    const int64_t slot = bin.slots[k];
    const scalar_t* gp = gv.at(slot);
    const scalar_t mx = gp[0], ca = gp[2], cb = gp[3], cc = gp[4], o = gp[5];
    const scalar_t* col = gv.color(slot);
    scalar_t* out = isect_grads + bin.isect_rows[k] * row;
    if constexpr (kVector) {
      const f32v zero = {};
      const i32v zero_i = {};
      const i32v order = zero_i + static_cast<int32_t>(kk);
      // per-lane sums of the Gaussian's gradient: mean x, mean y, conic a, b, c, opacity, colours
      f32v l_mx[kParts], l_my[kParts], l_a[kParts], l_b[kParts], l_c[kParts], l_o[kParts], l_col[kCols][kParts];
      f32v lane[kParts];
      for (int64_t q = 0; q < kParts; ++q) {
        l_mx[q] = l_my[q] = l_a[q] = l_b[q] = l_c[q] = l_o[q] = zero;
        for (int64_t c = 0; c < C; ++c) l_col[c][q] = zero;
        for (int64_t i = 0; i < kLanes; ++i) lane[q][i] = static_cast<float>(q * kLanes + i);
      }
      bool touched = false;
      const int32_t* lst_p = lst.data();
      const int32_t kk32 = static_cast<int32_t>(kk);
      for_each_covered_row<true>(gv, slot, x0, x1, y0, y1, tw,
                                 [lst_p, kk32](int64_t p0) { return lanes_above(lst_p + p0, kk32); },
                                 [&](int64_t p0, int64_t xc, float dy, uint32_t mask, const float* abuf,
                                     const float* ebuf, const float* rbuf) {
        touched = true;
        const float dx0 = static_cast<float>(xc) + 0.5f - mx;
        for (int64_t q = 0; q < kParts; ++q) {
          const int64_t off = q * kLanes, p = p0 + off;
          if (part_bits(mask, off) == 0) continue;  // every alpha 0: no lane active
          const f32v alpha = load_v<f32v>(abuf + off), vis = load_v<f32v>(ebuf + off), ra = load_v<f32v>(rbuf + off);
          f32v t = load_v<f32v>(T.data() + p);
          const f32v tva = load_v<f32v>(TfvA.data() + p);
          const i32v active = (alpha != 0.0f) & (order < load_v<i32v>(lst.data() + p));
          const f32v ti = t * ra;
          t = active ? ti : t;
          store_v(T.data() + p, t);
          const f32v fac = alpha * ti;
          f32v v_al = tva * ra;
          for (int64_t c = 0; c < C; ++c) {
            f32v sv = load_v<f32v>(S.data() + c * stride + p);
            const f32v vi = load_v<f32v>(vimg.data() + c * stride + p);
            l_col[c][q] = active ? l_col[c][q] + fac * vi : l_col[c][q];
            v_al = v_al + (col[c] * ti - sv * ra) * vi;
            sv = active ? sv + col[c] * fac : sv;
            store_v(S.data() + c * stride + p, sv);
          }
          const f32v raw = o * vis;
          const i32v gate = active & (raw < static_cast<float>(kMaxAlpha));
          const f32v v_sigma = -raw * v_al;
          const f32v dx = dx0 + lane[q];
          l_o[q] = gate ? l_o[q] + vis * v_al : l_o[q];
          l_a[q] = gate ? l_a[q] + 0.5f * dx * dx * v_sigma : l_a[q];
          l_b[q] = gate ? l_b[q] + dx * dy * v_sigma : l_b[q];
          l_c[q] = gate ? l_c[q] + 0.5f * dy * dy * v_sigma : l_c[q];
          l_mx[q] = gate ? l_mx[q] - (ca * dx + cb * dy) * v_sigma : l_mx[q];
          l_my[q] = gate ? l_my[q] - (cb * dx + cc * dy) * v_sigma : l_my[q];
        }
      });
      if (!touched) continue;
      row_written[bin.isect_rows[k]] = 1;
      out[0] = sum_lanes(l_mx);
      out[1] = sum_lanes(l_my);
      out[2] = sum_lanes(l_a);
      out[3] = sum_lanes(l_b);
      out[4] = sum_lanes(l_c);
      out[5] = sum_lanes(l_o);
      for (int64_t c = 0; c < C; ++c) out[6 + c] = sum_lanes(l_col[c]);
    } else {
      scalar_t g_mx = 0, g_my = 0, g_a = 0, g_b = 0, g_c = 0, g_o = 0;
      std::fill(gcol, gcol + C, scalar_t(0));
      for_each_covered_row<true>(gv, slot, x0, x1, y0, y1, tw, AllLanes{},
                                 [&](int64_t p0, int64_t xc, scalar_t dy, uint32_t mask, const scalar_t* abuf,
                                     const scalar_t* ebuf, const scalar_t* rbuf) {
        for (uint32_t m = mask; m != 0; m &= m - 1) {
          const int64_t i = __builtin_ctz(m), p = p0 + i;
          if (kk >= lst[p]) continue;
          const scalar_t alpha = abuf[i], vis = ebuf[i], ra = rbuf[i];
          const scalar_t dx = scalar_t(xc + i) + scalar_t(0.5) - mx;
          const scalar_t raw = o * vis;
          const scalar_t Ti = T[p] * ra;
          T[p] = Ti;
          const scalar_t fac = alpha * Ti;
          scalar_t v_al = TfvA[p] * ra;
          for (int64_t c = 0; c < C; ++c) {
            const scalar_t vi = vimg[c * stride + p];
            scalar_t& sv = S[c * stride + p];
            gcol[c] += fac * vi;
            v_al += (col[c] * Ti - sv * ra) * vi;
            sv += col[c] * fac;
          }
          if (raw < scalar_t(kMaxAlpha)) {
            const scalar_t v_sigma = -raw * v_al;
            g_o += vis * v_al;
            g_a += scalar_t(0.5) * dx * dx * v_sigma;
            g_b += dx * dy * v_sigma;
            g_c += scalar_t(0.5) * dy * dy * v_sigma;
            g_mx -= (ca * dx + cb * dy) * v_sigma;
            g_my -= (cb * dx + cc * dy) * v_sigma;
          }
        }
      });
      out[0] = g_mx;
      out[1] = g_my;
      out[2] = g_a;
      out[3] = g_b;
      out[4] = g_c;
      out[5] = g_o;
      for (int64_t c = 0; c < C; ++c) out[6 + c] = gcol[c];
      row_written[bin.isect_rows[k]] = 1;
    }
  }
}

void check_inputs(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& colors,
                  const at::Tensor& opacities, const at::Tensor& extents) {
  for (const auto* t : {&means2d, &conics, &colors, &opacities, &extents}) {
    TORCH_CHECK(t->device().is_cpu(), "abcgs cpu rasterizer: tensors must be on the CPU");
    TORCH_CHECK(t->is_contiguous(), "abcgs cpu rasterizer: tensors must be contiguous");
    TORCH_CHECK(t->scalar_type() == colors.scalar_type(), "abcgs cpu rasterizer: all float inputs must share a dtype");
  }
  const int64_t n = means2d.size(0);
  TORCH_CHECK(means2d.dim() == 2 && means2d.size(1) == 2, "means2d must be (N, 2)");
  TORCH_CHECK(conics.dim() == 2 && conics.size(1) == 3 && conics.size(0) == n, "conics must be (N, 3)");
  TORCH_CHECK(colors.dim() == 2 && colors.size(0) == n, "colors must be (N, C)");
  TORCH_CHECK(opacities.dim() == 1 && opacities.size(0) == n, "opacities must be (N,)");
  TORCH_CHECK(extents.dim() == 2 && extents.size(1) == 2 && extents.size(0) == n, "extents must be (N, 2)");
}

}  // namespace

// Sorts by `depths`, bins and blends the colours (N, C) and, with depth_channel, the depths as channel C (RGB+D).
// Returns (image (H, W, C [+ 1]), transmittance (H, W), last (H, W) int32,
//          tile_offsets, slots, order, slot_offsets, isect_rows, packed params (V, 8), packed colours (V, C),
//          blended (M) uint8) — the last eight are saved for backward. Tile t's Gaussians, front to back, are
//          order[slots[tile_offsets[t] : tile_offsets[t + 1]]].
std::vector<at::Tensor> rasterize_forward(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& colors,
                                          const at::Tensor& opacities, const at::Tensor& depths,
                                          const at::Tensor& extents, int64_t width, int64_t height,
                                          int64_t tile_size, bool depth_channel) {
  check_inputs(means2d, conics, colors, opacities, extents);
  TORCH_CHECK(depths.dim() == 1 && depths.size(0) == means2d.size(0) && depths.is_contiguous() &&
                  depths.scalar_type() == colors.scalar_type(),
              "depths must be a contiguous (N,) tensor of the colours' dtype");
  const int64_t n = means2d.size(0), C = colors.size(1) + (depth_channel ? 1 : 0);  // + the depth channel (RGB+D)
  at::Tensor order = AT_DISPATCH_FLOATING_TYPES(colors.scalar_type(), "abcgs_depth_order", [&] {
    return depth_order<scalar_t>(depths.data_ptr<scalar_t>(), extents.data_ptr<scalar_t>(), n);
  });
  auto opts = colors.options();
  at::Tensor image = at::empty({height, width, C}, opts);
  at::Tensor trans = at::empty({height, width}, opts);
  at::Tensor last = at::empty({height, width}, at::kInt);
  at::Tensor packed_params, packed_colors, blended;
  std::optional<Binning> binning;
  AT_DISPATCH_FLOATING_TYPES(colors.scalar_type(), "abcgs_rasterize_forward", [&] {
    const GaussianView<scalar_t> gv(means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                                    colors.data_ptr<scalar_t>(), opacities.data_ptr<scalar_t>(),
                                    extents.data_ptr<scalar_t>(), colors.size(1), n, order, opts,
                                    depth_channel ? depths.data_ptr<scalar_t>() : nullptr);
    binning.emplace(bin_tiles(gv, order, width, height, tile_size));
    const Binning& bin = *binning;
    blended = at::zeros({bin.num_isects()}, at::kByte);
    uint8_t* bl = blended.data_ptr<uint8_t>();
    packed_params = gv.params_t;
    packed_colors = gv.colors_t;
    scalar_t* im = image.data_ptr<scalar_t>();
    scalar_t* tr = trans.data_ptr<scalar_t>();
    int32_t* ls = last.data_ptr<int32_t>();
    for_each_tile(bin.tiles_x * bin.tiles_y,
                  [&](int64_t t) {
                    // RGB and RGB + depth with the channel loops unrolled at compile time
                    if (C == 3) forward_tile<scalar_t, 3>(gv, bin, t, width, height, tile_size, im, tr, ls, bl);
                    else if (C == 4) forward_tile<scalar_t, 4>(gv, bin, t, width, height, tile_size, im, tr, ls, bl);
                    else forward_tile<scalar_t, 0>(gv, bin, t, width, height, tile_size, im, tr, ls, bl);
                  });
  });
  const Binning& bin = *binning;
  return {image, trans, last, bin.tile_offsets_t, bin.slots_t, bin.order_t, bin.slot_offsets_t, bin.isect_rows_t,
          packed_params, packed_colors, blended};
}

// Returns (v_means2d (N, 2), v_conics (N, 3), v_colors (N, C), v_opacities (N)).
std::vector<at::Tensor> rasterize_backward(const at::Tensor& means2d, const at::Tensor& conics,
                                           const at::Tensor& colors, const at::Tensor& opacities,
                                           const at::Tensor& extents, const at::Tensor& trans,
                                           const at::Tensor& last, const at::Tensor& tile_offsets,
                                           const at::Tensor& slots, const at::Tensor& order,
                                           const at::Tensor& slot_offsets, const at::Tensor& isect_rows,
                                           const at::Tensor& packed_params, const at::Tensor& packed_colors,
                                           const at::Tensor& blended, const at::Tensor& v_image,
                                           const at::Tensor& v_alpha, int64_t width, int64_t height,
                                           int64_t tile_size, const at::Tensor& scratch) {
  check_inputs(means2d, conics, colors, opacities, extents);
  // the forward pass's channels: the colours' and, for RGB+D, the depth channel it appended
  const int64_t n = means2d.size(0), C = packed_colors.size(1), row = 6 + C;
  Binning bin(tile_offsets, slots, order, slot_offsets, isect_rows, width, height, tile_size);
  const int64_t m = bin.num_isects();
  auto opts = colors.options();
  // the rows of the entries that blended are written by their tile (flagged in row_written); a large enough
  // `scratch` (float, the caller's, kept between calls) saves the allocation and the page faults of a fresh
  // buffer of M x (6 + C) values per call
  at::Tensor isect_grads = scratch.scalar_type() == colors.scalar_type() && scratch.is_contiguous() &&
                                   scratch.numel() >= m * row
                               ? scratch.view({-1}).narrow(0, 0, m * row).view({m, row})
                               : at::empty({m, row}, opts);
  at::Tensor v_means2d = at::zeros({n, 2}, opts), v_conics = at::zeros({n, 3}, opts);
  at::Tensor v_colors = at::zeros({n, C}, opts), v_opac = at::zeros({n}, opts);
  at::Tensor vi = v_image.contiguous().to(colors.scalar_type());
  at::Tensor va = v_alpha.contiguous().to(colors.scalar_type());
  AT_DISPATCH_FLOATING_TYPES(colors.scalar_type(), "abcgs_rasterize_backward", [&] {
    const GaussianView<scalar_t> gv(packed_params, packed_colors, bin);
    const scalar_t* tr = trans.data_ptr<scalar_t>();
    const int32_t* ls = last.data_ptr<int32_t>();
    const scalar_t* vip = vi.data_ptr<scalar_t>();
    const scalar_t* vap = va.data_ptr<scalar_t>();
    scalar_t* ig = isect_grads.data_ptr<scalar_t>();
    TORCH_CHECK(blended.scalar_type() == at::kByte && blended.numel() == m && blended.is_contiguous(),
                "rasterize_backward: the forward pass's blend flags do not match the binning");
    const uint8_t* bl = blended.data_ptr<uint8_t>();
    at::Tensor written = at::zeros({m}, at::kByte);
    uint8_t* rw = written.data_ptr<uint8_t>();
    for_each_tile(bin.tiles_x * bin.tiles_y, [&](int64_t t) {
      if (C == 3) backward_tile<scalar_t, 3>(gv, bin, t, width, height, tile_size, tr, ls, vip, vap, bl, ig, rw);
      else if (C == 4) backward_tile<scalar_t, 4>(gv, bin, t, width, height, tile_size, tr, ls, vip, vap, bl, ig, rw);
      else backward_tile<scalar_t, 0>(gv, bin, t, width, height, tile_size, tr, ls, vip, vap, bl, ig, rw);
    });
    scalar_t* vm = v_means2d.data_ptr<scalar_t>();
    scalar_t* vc = v_conics.data_ptr<scalar_t>();
    scalar_t* vcol = v_colors.data_ptr<scalar_t>();
    scalar_t* vo = v_opac.data_ptr<scalar_t>();
    // each slot's rows (consecutive, in tile order) summed into its Gaussian's entries (one slot per Gaussian)
    abcgs::parallel_range(bin.num_slots(), 4096, [&](int64_t begin, int64_t end) {
      scalar_t acc[6 + 64];
      for (int64_t k = begin; k < end; ++k) {
        const int64_t g = bin.order[k], j0 = bin.slot_offsets[k], j1 = bin.slot_offsets[k + 1];
        if (j0 == j1) continue;
        if (C > 64) {
          for (int64_t j = j0; j < j1; ++j) {
            if (!rw[j]) continue;
            const scalar_t* r = ig + j * row;
            vm[2 * g] += r[0];
            vm[2 * g + 1] += r[1];
            vc[3 * g] += r[2];
            vc[3 * g + 1] += r[3];
            vc[3 * g + 2] += r[4];
            vo[g] += r[5];
            for (int64_t c = 0; c < C; ++c) vcol[g * C + c] += r[6 + c];
          }
          continue;
        }
        std::fill(acc, acc + row, scalar_t(0));
        bool any = false;
        for (int64_t j = j0; j < j1; ++j) {
          if (!rw[j]) continue;
          any = true;
          const scalar_t* r = ig + j * row;
          for (int64_t i = 0; i < row; ++i) acc[i] += r[i];
        }
        // a Gaussian that blended nowhere keeps its zero-initialised entries: most of a large scene's slots lie
        // behind opaque pixels, and their scattered writes would each miss the cache
        if (!any) continue;
        vm[2 * g] = acc[0];
        vm[2 * g + 1] = acc[1];
        vc[3 * g] = acc[2];
        vc[3 * g + 1] = acc[3];
        vc[3 * g + 2] = acc[4];
        vo[g] = acc[5];
        for (int64_t c = 0; c < C; ++c) vcol[g * C + c] = acc[6 + c];
      }
    });
  });
  return {v_means2d, v_conics, v_colors, v_opac};
}

// projection_cpu.cpp
std::vector<at::Tensor> project_forward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                        const at::Tensor& opacities, const at::Tensor& viewmat, const at::Tensor& K,
                                        int64_t width, int64_t height, double near, double far, double eps2d);
std::vector<at::Tensor> project_backward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                         const at::Tensor& viewmat, const at::Tensor& K, int64_t width, int64_t height,
                                         double near, double far, double eps2d, const at::Tensor& v_means2d,
                                         const at::Tensor& v_conics, const at::Tensor& v_depths);

// frozen_cpu.cpp
std::vector<at::Tensor> blend_weights(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& opacities,
                                      const at::Tensor& depths, const at::Tensor& extents, int64_t width,
                                      int64_t height, int64_t tile_size);
at::Tensor frozen_blend_forward(const at::Tensor& tile_runs, const at::Tensor& run_group, const at::Tensor& run_entries,
                                const at::Tensor& entry_pix, const at::Tensor& entry_w, const at::Tensor& colors,
                                int64_t width, int64_t height, int64_t tile_size);
at::Tensor frozen_blend_backward(const at::Tensor& tile_runs, const at::Tensor& run_group, const at::Tensor& run_entries,
                                 const at::Tensor& entry_pix, const at::Tensor& entry_w, const at::Tensor& group_runs,
                                 const at::Tensor& group_offsets, const at::Tensor& v_image, int64_t width,
                                 int64_t height, int64_t tile_size);

// sh_cpu.cpp
at::Tensor sh_colors_forward(const at::Tensor& sh0, const at::Tensor& shN, const at::Tensor& means,
                             const at::Tensor& campos, const at::Tensor& mask, int64_t degree);
std::vector<at::Tensor> sh_colors_backward(const at::Tensor& sh0, const at::Tensor& shN, const at::Tensor& means,
                                           const at::Tensor& campos, const at::Tensor& mask, int64_t degree,
                                           const at::Tensor& v_colors, bool need_shN, bool need_means);

// knn_cpu.cpp
at::Tensor pair_dots(const at::Tensor& a, const at::Tensor& b, const at::Tensor& ia, const at::Tensor& ib);
std::vector<at::Tensor> topk_columns(const at::Tensor& s, int64_t k);
std::vector<at::Tensor> topk_dots_both(const at::Tensor& a, const at::Tensor& b, int64_t ka, int64_t kb,
                                       bool bf16_products);
bool bf16_dot_available();
at::Tensor rerank_topk(const at::Tensor& own, const at::Tensor& other, const at::Tensor& cand, int64_t k);

// image_loss_cpu.cpp
std::vector<at::Tensor> l1_ssim_forward(const at::Tensor& render, const at::Tensor& target, const at::Tensor& window,
                                        double c1, double c2);

// drift_cpu.cpp
std::vector<at::Tensor> scale_drift(const at::Tensor& log_scales, const at::Tensor& start);
std::vector<at::Tensor> opacity_drift(const at::Tensor& logits, const at::Tensor& start);

// batch_cpu.cpp
std::vector<at::Tensor> project_batch_forward(const at::Tensor& means, const at::Tensor& quats,
                                              const at::Tensor& scales, const at::Tensor& opacities,
                                              const at::Tensor& viewmats, const at::Tensor& Ks, int64_t width,
                                              int64_t height, double near, double far, double eps2d,
                                              const at::Tensor& sh0, const at::Tensor& shN, int64_t sh_degree);
std::vector<at::Tensor> project_batch_backward(const at::Tensor& means, const at::Tensor& quats,
                                               const at::Tensor& scales, const at::Tensor& viewmats,
                                               const at::Tensor& Ks, int64_t width, int64_t height, double near,
                                               double far, double eps2d, const at::Tensor& v_means2d,
                                               const at::Tensor& v_conics, const at::Tensor& v_depths,
                                               const at::Tensor& sh0, const at::Tensor& shN,
                                               const at::Tensor& campos, const at::Tensor& visible,
                                               int64_t sh_degree, const at::Tensor& v_colors, bool need_shN,
                                               bool need_means);
std::vector<at::Tensor> rasterize_batch_forward(const at::Tensor& means2d, const at::Tensor& conics,
                                                const at::Tensor& colors, const at::Tensor& opacities,
                                                const at::Tensor& depths, const at::Tensor& extents, int64_t width,
                                                int64_t height, int64_t tile_size, bool depth_channel, bool save);
std::vector<at::Tensor> rasterize_batch_backward(const at::Tensor& means2d, const at::Tensor& conics,
                                                 const at::Tensor& colors, const at::Tensor& opacities,
                                                 const at::Tensor& depths, const at::Tensor& extents,
                                                 const at::Tensor& trans, const at::Tensor& last,
                                                 const std::vector<at::Tensor>& saved, const at::Tensor& v_image,
                                                 const at::Tensor& v_alpha, int64_t width, int64_t height,
                                                 int64_t tile_size, bool depth_channel, const at::Tensor& scratch);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("project_forward", &project_forward, "abcgs fused EWA projection forward (CPU)");
  m.def("project_backward", &project_backward, "abcgs fused EWA projection backward (CPU)");
  m.def("rasterize_forward", &rasterize_forward, "abcgs tile rasterizer forward (CPU)");
  m.def("rasterize_backward", &rasterize_backward, "abcgs tile rasterizer backward (CPU)");
  m.def("blend_weights", &blend_weights, "the per-pixel blending weights of a view, for frozen geometry (CPU)");
  m.def("frozen_blend_forward", &frozen_blend_forward, "a view's recorded blending map applied to colours (CPU)");
  m.def("frozen_blend_backward", &frozen_blend_backward, "the transpose of a view's recorded blending map (CPU)");
  m.def("sh_colors_forward", &sh_colors_forward, "abcgs fused SH colours of the masked Gaussians (CPU)");
  m.def("sh_colors_backward", &sh_colors_backward, "abcgs fused SH colours backward (CPU)");
  m.def("pair_dots", &pair_dots, "dot products of selected row pairs of two float32 matrices (CPU)");
  m.def("topk_columns", &topk_columns, "top-k of every column of a row-major matrix, one pass over rows (CPU)");
  m.def("topk_dots_both", &topk_dots_both,
        "the largest dot products of each row of a with the rows of b and vice versa, one pass (CPU)",
        py::arg("a"), py::arg("b"), py::arg("ka"), py::arg("kb"), py::arg("bf16_products") = false);
  m.def("bf16_dot_available", &bf16_dot_available,
        "whether this build has the AVX512-BF16 products of topk_dots_both (a CPU with AVX512-BF16 and AVX512-VL)");
  m.def("rerank_topk", &rerank_topk, "the k candidates with the largest exact dot products, per row (CPU)");
  m.def("l1_ssim_forward", &l1_ssim_forward, "mean L1 and SSIM of two images and their gradients (CPU)");
  m.def("project_batch_forward", &project_batch_forward, "projection and SH colours into C cameras, one call (CPU)");
  m.def("project_batch_backward", &project_batch_backward, "backward of project_batch_forward, summed over cameras (CPU)");
  m.def("rasterize_batch_forward", &rasterize_batch_forward, "tile rasterizer over C cameras, one call (CPU)");
  m.def("rasterize_batch_backward", &rasterize_batch_backward, "backward of rasterize_batch_forward (CPU)");
  m.def("scale_drift", &scale_drift, "mean drift of the scales from the start and its gradient (CPU)");
  m.def("opacity_drift", &opacity_drift, "mean drift of the opacities from the start and its gradient (CPU)");
  m.def("set_kernel_threads", &abcgs::set_kernel_threads, "threads of the CPU kernels (0 = all hardware threads)");
  m.def("kernel_threads", &abcgs::kernel_threads, "threads the CPU kernels use now");
}
