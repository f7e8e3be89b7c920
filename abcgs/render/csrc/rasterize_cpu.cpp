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

#include <torch/extension.h>

#include "parallel.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <vector>

namespace {

constexpr double kAlphaThreshold = 1.0 / 255.0;
constexpr double kMaxAlpha = 0.99;
constexpr double kTransmittanceEps = 1e-4;

// Tile lists and their inverse (per-Gaussian intersection lists), stored in tensors so the forward
// pass can hand them to autograd for the backward pass without copies.
struct Binning {
  int64_t tiles_x = 0, tiles_y = 0;
  at::Tensor tile_offsets_t, ids_t, gauss_offsets_t, gauss_isect_t;
  const int64_t* tile_offsets = nullptr;   // (n_tiles + 1) start of each tile's list in `ids`
  const int32_t* ids = nullptr;            // (M) Gaussian index per intersection, depth-sorted in a tile
  const int64_t* gauss_offsets = nullptr;  // (N + 1) start of each Gaussian's row in `gauss_isect`
  const int64_t* gauss_isect = nullptr;    // (M) intersection indices of each Gaussian, in tile order
  int64_t num_isects() const { return ids_t.numel(); }

  Binning(at::Tensor tile_offsets_, at::Tensor ids_, at::Tensor gauss_offsets_, at::Tensor gauss_isect_,
          int64_t width, int64_t height, int64_t tile)
      : tiles_x((width + tile - 1) / tile),
        tiles_y((height + tile - 1) / tile),
        tile_offsets_t(tile_offsets_.contiguous()),
        ids_t(ids_.contiguous()),
        gauss_offsets_t(gauss_offsets_.contiguous()),
        gauss_isect_t(gauss_isect_.contiguous()) {
    TORCH_CHECK(tile_offsets_t.numel() == tiles_x * tiles_y + 1, "binning does not match the image size");
    tile_offsets = tile_offsets_t.data_ptr<int64_t>();
    ids = ids_t.data_ptr<int32_t>();
    gauss_offsets = gauss_offsets_t.data_ptr<int64_t>();
    gauss_isect = gauss_isect_t.data_ptr<int64_t>();
  }
};

// Front-to-back order of the Gaussians with a positive extent: a stable LSD radix sort (8-bit digits) of
// the depth bits mapped to order-preserving unsigned keys. Ties keep index order and NaN depths go last,
// i.e. the same permutation as `torch.argsort(depths[extents[:, 0] > 0], stable=True)` (one exception: -0.0
// sorts before +0.0, which torch treats as a tie; projected Gaussians have depth > near > 0).
template <typename scalar_t>
std::vector<int64_t> depth_order(const scalar_t* depth, const scalar_t* ext, int64_t n) {
  using key_t = std::conditional_t<sizeof(scalar_t) == 4, uint32_t, uint64_t>;
  constexpr key_t kSign = key_t(1) << (8 * sizeof(key_t) - 1);
  std::vector<key_t> keys, keys_tmp;
  std::vector<int64_t> idx, idx_tmp;
  keys.reserve(n);
  idx.reserve(n);
  for (int64_t g = 0; g < n; ++g) {
    if (!(ext[2 * g] > 0)) continue;
    const scalar_t d = depth[g];
    key_t k = ~key_t(0);
    if (!std::isnan(d)) {
      std::memcpy(&k, &d, sizeof(k));
      k = (k & kSign) ? ~k : (k | kSign);
    }
    keys.push_back(k);
    idx.push_back(g);
  }
  const int64_t m = static_cast<int64_t>(keys.size());
  keys_tmp.resize(m);
  idx_tmp.resize(m);
  for (int shift = 0; shift < static_cast<int>(8 * sizeof(key_t)); shift += 8) {
    int64_t count[257] = {0};
    for (int64_t i = 0; i < m; ++i) count[((keys[i] >> shift) & 0xff) + 1]++;
    if (std::find(count + 1, count + 257, m) != count + 257) continue;  // one bucket: order unchanged
    for (int b = 0; b < 256; ++b) count[b + 1] += count[b];
    for (int64_t i = 0; i < m; ++i) {
      const int64_t pos = count[(keys[i] >> shift) & 0xff]++;
      keys_tmp[pos] = keys[i];
      idx_tmp[pos] = idx[i];
    }
    keys.swap(keys_tmp);
    idx.swap(idx_tmp);
  }
  return idx;
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

// Sort the Gaussians front to back and bin them into tiles (see `depth_order` and `tile_box`).
template <typename scalar_t>
Binning bin_gaussians(const scalar_t* means2d, const scalar_t* extents, const scalar_t* depths, int64_t n,
                      int64_t width, int64_t height, int64_t tile) {
  const int64_t tiles_x = (width + tile - 1) / tile, tiles_y = (height + tile - 1) / tile;
  const int64_t n_tiles = tiles_x * tiles_y;
  const std::vector<int64_t> ord = depth_order(depths, extents, n);
  const int64_t n_vis = static_cast<int64_t>(ord.size());
  std::vector<int32_t> boxes(4 * n_vis);
  std::vector<uint8_t> hit(n_vis);
  for (int64_t k = 0; k < n_vis; ++k) {
    const int64_t g = ord[k];
    hit[k] = tile_box(means2d[2 * g], means2d[2 * g + 1], extents[2 * g], extents[2 * g + 1], width, height, tile,
                      &boxes[4 * k]);
  }

  at::Tensor tile_offsets = at::zeros({n_tiles + 1}, at::kLong);
  at::Tensor gauss_offsets = at::zeros({n + 1}, at::kLong);
  int64_t* toff = tile_offsets.data_ptr<int64_t>();
  int64_t* goff = gauss_offsets.data_ptr<int64_t>();
  for (int64_t k = 0; k < n_vis; ++k) {
    if (!hit[k]) continue;
    const int32_t* r = &boxes[4 * k];
    for (int64_t ty = r[1]; ty <= r[3]; ++ty)
      for (int64_t tx = r[0]; tx <= r[2]; ++tx) toff[ty * tiles_x + tx + 1]++;
    goff[ord[k] + 1] = int64_t(r[2] - r[0] + 1) * (r[3] - r[1] + 1);
  }
  for (int64_t t = 0; t < n_tiles; ++t) toff[t + 1] += toff[t];
  for (int64_t g = 0; g < n; ++g) goff[g + 1] += goff[g];
  const int64_t m = toff[n_tiles];
  at::Tensor ids = at::empty({m}, at::kInt);
  at::Tensor gauss_isect = at::empty({m}, at::kLong);
  int32_t* id = ids.data_ptr<int32_t>();
  int64_t* gi = gauss_isect.data_ptr<int64_t>();
  std::vector<int64_t> cursor(toff, toff + n_tiles);
  for (int64_t k = 0; k < n_vis; ++k) {
    if (!hit[k]) continue;
    const int64_t g = ord[k];
    const int32_t* r = &boxes[4 * k];
    int64_t j = goff[g];
    for (int64_t ty = r[1]; ty <= r[3]; ++ty)
      for (int64_t tx = r[0]; tx <= r[2]; ++tx) {
        const int64_t pos = cursor[ty * tiles_x + tx]++;
        id[pos] = static_cast<int32_t>(g);
        gi[j++] = pos;
      }
  }
  return Binning(tile_offsets, ids, gauss_offsets, gauss_isect, width, height, tile);
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

// Columns [xa, xb) of one pixel row (offset dy from the mean) inside the level set sigma <= s_max,
// where s_max = log(255 o) bounds where alpha >= 1/255 can hold. Padded so that rounding can only add
// columns (each one is then tested exactly), never drop one. Returns false when the row misses it.
template <typename scalar_t>
inline bool row_span(scalar_t mx, scalar_t dy, scalar_t ca, scalar_t cb, scalar_t cc, scalar_t s_max, int64_t lo,
                     int64_t hi, int64_t& xa, int64_t& xb) {
  const double bdy = double(cb) * dy;
  const double disc = bdy * bdy - double(ca) * (double(cc) * dy * dy - 2.0 * s_max);
  if (!(disc >= 0.0) || !(ca > 0)) {
    if (ca > 0) return false;
    xa = lo;  // degenerate conic: no pruning, the exact test decides
    xb = hi;
    return true;
  }
  const double r = std::sqrt(disc);
  const double pad = 1e-3 * (1.0 + std::abs(double(mx)));
  const double x0 = double(mx) + (-bdy - r) / ca - 0.5 - pad, x1 = double(mx) + (-bdy + r) / ca - 0.5 + pad;
  xa = std::max<int64_t>(lo, static_cast<int64_t>(std::ceil(x0)));
  xb = std::min<int64_t>(hi, static_cast<int64_t>(std::floor(x1)) + 1);
  return xa < xb;
}

// Upper bound of the exponent at which alpha = o exp(-sigma) can still reach 1/255 (with margin).
template <typename scalar_t>
inline scalar_t sigma_limit(scalar_t o) {
  return static_cast<scalar_t>(std::log(std::max(1.0, double(o) * 255.0)) + 1e-3);
}

// e^x for float without a libm call, so that the per-row loop below vectorises (AVX2: 8 lanes).
// Cephes' expf: Cody-Waite reduction by ln 2, degree-6 polynomial, scale by 2^n through the exponent bits;
// relative error ~1e-7 on the range used here (x in [-88, 0]). Forward and backward share it, so
// their skip/stop decisions agree exactly. Doubles use std::exp (exact gradient checks).
inline float exp_fast(float x) {
  x = std::min(88.0f, std::max(-87.0f, x));
  const float n = std::floor(x * 1.44269504088896341f + 0.5f);
  const float f = x - n * 0.693359375f + n * 2.12194440e-4f;
  const float z = f * f;
  const float p = (((((1.9875691500e-4f * f + 1.3981999507e-3f) * f + 8.3334519073e-3f) * f + 4.1665795894e-2f) * f +
                    1.6666665459e-1f) * f + 5.0000001201e-1f) * z + f + 1.0f;
  const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof(scale));
  return p * scale;
}
inline float exp_neg(float s) { return exp_fast(-s); }
inline double exp_neg(double s) { return std::exp(-s); }

// Pixels per call of row_alpha: a fixed trip count, so that the loop compiles to whole vectors (one AVX-512
// or two AVX2 iterations) with no scalar remainder. A Gaussian's span in a tile row is typically 2-8 pixels,
// which a loop over [xa, xb) ran entirely in its scalar remainder (measured on fern: 3 of every 10 forward
// cycles in scalar exp). Lanes outside the span are computed and ignored.
constexpr int64_t kRowChunk = 16;

// Alpha (0 where skipped: sigma < 0 or alpha < 1/255) and exp(-sigma) for the kRowChunk pixels
// x = xa + first + i (i < kRowChunk) of one row at offset dy from the mean: the branch-free part of blending.
// dx is formed as (xa + 0.5 - mx) + (first + i), the same rounding for every chunk of a span.
template <typename scalar_t>
inline void row_alpha(int64_t xa, int64_t first, scalar_t mx, scalar_t dy, scalar_t ca, scalar_t cb, scalar_t cc,
                      scalar_t o, scalar_t* __restrict alpha, scalar_t* __restrict vis) {
  const scalar_t half_cdy2 = scalar_t(0.5) * cc * dy * dy, cbdy = cb * dy;
  const scalar_t x0 = scalar_t(xa) + scalar_t(0.5) - mx;
  for (int64_t i = 0; i < kRowChunk; ++i) {
    const scalar_t dx = x0 + (scalar_t(first) + scalar_t(int32_t(i)));  // = x0 + (first + i): exact sums
    const scalar_t sigma = scalar_t(0.5) * ca * dx * dx + half_cdy2 + cbdy * dx;
    const scalar_t e = exp_neg(sigma);
    const scalar_t a = std::min(scalar_t(kMaxAlpha), o * e);
    const scalar_t a_kept = a >= scalar_t(kAlphaThreshold) ? a : scalar_t(0);  // selects, not a bool mask:
    alpha[i] = sigma >= scalar_t(0) ? a_kept : scalar_t(0);                    // GCC vectorises these
    vis[i] = e;
  }
}

template <typename scalar_t>
struct GaussianView {
  const scalar_t* means2d;   // (N, 2)
  const scalar_t* conics;    // (N, 3)
  const scalar_t* colors;    // (N, C)
  const scalar_t* opac;      // (N)
  const scalar_t* extents;   // (N, 2)
  int64_t channels;
};

// Visit, row by row, the pixels of the tile [x0, x1) x [y0, y1) where Gaussian g can reach alpha >= 1/255:
// its box clipped to the tile, each row narrowed to the ellipse's span, alpha (0 = skipped) and exp(-sigma)
// of the row computed in one vectorised pass. fn(p, x, dy, alpha, vis) gets the tile-local pixel index.
template <typename scalar_t, typename F>
inline void for_each_covered_pixel(const GaussianView<scalar_t>& gv, int64_t g, int64_t x0, int64_t x1, int64_t y0,
                                   int64_t y1, int64_t tw, F&& fn) {
  alignas(64) scalar_t abuf[kRowChunk], ebuf[kRowChunk];
  const scalar_t mx = gv.means2d[2 * g], my = gv.means2d[2 * g + 1];
  const scalar_t ca = gv.conics[3 * g], cb = gv.conics[3 * g + 1], cc = gv.conics[3 * g + 2];
  const scalar_t o = gv.opac[g];
  int64_t xa, xb, ya, yb;
  box_in_tile<scalar_t>(mx, gv.extents[2 * g], x0, x1, xa, xb);
  box_in_tile<scalar_t>(my, gv.extents[2 * g + 1], y0, y1, ya, yb);
  const scalar_t s_max = sigma_limit(o);
  for (int64_t y = ya; y < yb; ++y) {
    const scalar_t dy = scalar_t(y) + scalar_t(0.5) - my;
    int64_t xs, xe;
    if (!row_span<scalar_t>(mx, dy, ca, cb, cc, s_max, xa, xb, xs, xe)) continue;
    const int64_t row = (y - y0) * tw - x0;
    for (int64_t first = 0; xs + first < xe; first += kRowChunk) {
      row_alpha<scalar_t>(xs, first, mx, dy, ca, cb, cc, o, abuf, ebuf);
      const int64_t xb = xs + first, n = std::min(kRowChunk, xe - xb);
      for (int64_t i = 0; i < n; ++i) {
        const scalar_t alpha = abuf[i];
        if (alpha != scalar_t(0)) fn(row + xb + i, xb + i, dy, alpha, ebuf[i]);
      }
    }
  }
}

// Forward pass for one tile. Writes image (H, W, C), transmittance (H, W) and, per pixel, the number
// of tile-list entries up to and including the last Gaussian blended (0 = none).
template <typename scalar_t>
void forward_tile(const GaussianView<scalar_t>& gv, const Binning& bin, int64_t tile, int64_t width, int64_t height,
                  int64_t tile_size, scalar_t* image, scalar_t* trans, int32_t* last) {
  const int64_t C = gv.channels;
  const int64_t tx = tile % bin.tiles_x, ty = tile / bin.tiles_x;
  const int64_t x0 = tx * tile_size, y0 = ty * tile_size;
  const int64_t x1 = std::min(width, x0 + tile_size), y1 = std::min(height, y0 + tile_size);
  const int64_t tw = x1 - x0, th = y1 - y0, npix = tw * th;
  std::vector<scalar_t> T(npix, scalar_t(1)), acc(npix * C, scalar_t(0));
  std::vector<int32_t> lst(npix, 0);
  std::vector<uint8_t> done(npix, 0);
  int64_t remaining = npix;
  const int64_t start = bin.tile_offsets[tile], end = bin.tile_offsets[tile + 1];
  for (int64_t k = start; k < end && remaining > 0; ++k) {
    const int64_t g = bin.ids[k];
    const scalar_t* col = gv.colors + g * C;
    const int32_t order = static_cast<int32_t>(k - start + 1);
    for_each_covered_pixel(gv, g, x0, x1, y0, y1, tw,
                           [&](int64_t p, int64_t, scalar_t, scalar_t alpha, scalar_t) {
      if (done[p]) return;
      const scalar_t next_T = T[p] * (scalar_t(1) - alpha);
      if (next_T <= scalar_t(kTransmittanceEps)) {
        done[p] = 1;
        --remaining;
        return;
      }
      const scalar_t w = alpha * T[p];
      scalar_t* a = acc.data() + p * C;
      for (int64_t c = 0; c < C; ++c) a[c] += w * col[c];
      T[p] = next_T;
      lst[p] = order;
    });
  }
  for (int64_t y = y0; y < y1; ++y)
    for (int64_t x = x0; x < x1; ++x) {
      const int64_t p = (y - y0) * tw + (x - x0), q = y * width + x;
      trans[q] = T[p];
      last[q] = lst[p];
      for (int64_t c = 0; c < C; ++c) image[q * C + c] = acc[p * C + c];
    }
}

// Backward pass for one tile: walks the tile's list back to front, reconstructing each pixel's
// transmittance from its final value, and writes one gradient row per intersection:
// [d mean_x, d mean_y, d conic_a, d conic_b, d conic_c, d opacity, d color_0 .. d color_{C-1}].
template <typename scalar_t>
void backward_tile(const GaussianView<scalar_t>& gv, const Binning& bin, int64_t tile, int64_t width,
                   int64_t height, int64_t tile_size, const scalar_t* trans, const int32_t* last,
                   const scalar_t* v_image, const scalar_t* v_alpha, scalar_t* isect_grads) {
  const int64_t C = gv.channels, row = 6 + C;
  const int64_t tx = tile % bin.tiles_x, ty = tile / bin.tiles_x;
  const int64_t x0 = tx * tile_size, y0 = ty * tile_size;
  const int64_t x1 = std::min(width, x0 + tile_size), y1 = std::min(height, y0 + tile_size);
  const int64_t tw = x1 - x0, th = y1 - y0, npix = tw * th;
  const int64_t start = bin.tile_offsets[tile];
  std::vector<scalar_t> T(npix), Tfin(npix), S(npix * C, scalar_t(0)), vimg(npix * C), vA(npix);
  std::vector<int32_t> lst(npix);
  int32_t max_last = 0;
  for (int64_t y = y0; y < y1; ++y)
    for (int64_t x = x0; x < x1; ++x) {
      const int64_t p = (y - y0) * tw + (x - x0), q = y * width + x;
      T[p] = Tfin[p] = trans[q];
      lst[p] = last[q];
      max_last = std::max(max_last, last[q]);
      vA[p] = v_alpha[q];
      for (int64_t c = 0; c < C; ++c) vimg[p * C + c] = v_image[q * C + c];
    }
  std::vector<scalar_t> gcol(C);
  for (int64_t kk = max_last - 1; kk >= 0; --kk) {
    const int64_t k = start + kk;
    const int64_t g = bin.ids[k];
    const scalar_t mx = gv.means2d[2 * g];
    const scalar_t ca = gv.conics[3 * g], cb = gv.conics[3 * g + 1], cc = gv.conics[3 * g + 2];
    const scalar_t o = gv.opac[g];
    const scalar_t* col = gv.colors + g * C;
    scalar_t g_mx = 0, g_my = 0, g_a = 0, g_b = 0, g_c = 0, g_o = 0;
    std::fill(gcol.begin(), gcol.end(), scalar_t(0));
    for_each_covered_pixel(gv, g, x0, x1, y0, y1, tw,
                           [&](int64_t p, int64_t x, scalar_t dy, scalar_t alpha, scalar_t vis) {
      if (kk >= lst[p]) return;
      const scalar_t dx = scalar_t(x) + scalar_t(0.5) - mx;
      const scalar_t raw = o * vis;
      const scalar_t ra = scalar_t(1) / (scalar_t(1) - alpha);
      const scalar_t Ti = T[p] * ra;
      T[p] = Ti;
      const scalar_t fac = alpha * Ti;
      const scalar_t* vi = vimg.data() + p * C;
      scalar_t* s = S.data() + p * C;
      scalar_t v_al = vA[p] * Tfin[p] * ra;
      for (int64_t c = 0; c < C; ++c) {
        gcol[c] += fac * vi[c];
        v_al += (col[c] * Ti - s[c] * ra) * vi[c];
        s[c] += col[c] * fac;
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
    });
    scalar_t* out = isect_grads + k * row;
    out[0] = g_mx;
    out[1] = g_my;
    out[2] = g_a;
    out[3] = g_b;
    out[4] = g_c;
    out[5] = g_o;
    for (int64_t c = 0; c < C; ++c) out[6 + c] = gcol[c];
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

// Sorts by `depths`, bins and blends. Returns (image (H, W, C), transmittance (H, W), last (H, W) int32,
//          tile_offsets, ids, gauss_offsets, gauss_isect) — the last four are saved for backward.
std::vector<at::Tensor> rasterize_forward(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& colors,
                                          const at::Tensor& opacities, const at::Tensor& depths,
                                          const at::Tensor& extents, int64_t width, int64_t height,
                                          int64_t tile_size) {
  check_inputs(means2d, conics, colors, opacities, extents);
  TORCH_CHECK(depths.dim() == 1 && depths.size(0) == means2d.size(0) && depths.is_contiguous() &&
                  depths.scalar_type() == colors.scalar_type(),
              "depths must be a contiguous (N,) tensor of the colours' dtype");
  const int64_t n = means2d.size(0), C = colors.size(1);
  Binning bin = AT_DISPATCH_FLOATING_TYPES(colors.scalar_type(), "abcgs_bin_gaussians", [&] {
    return bin_gaussians<scalar_t>(means2d.data_ptr<scalar_t>(), extents.data_ptr<scalar_t>(),
                                   depths.data_ptr<scalar_t>(), n, width, height, tile_size);
  });
  auto opts = colors.options();
  at::Tensor image = at::zeros({height, width, C}, opts);
  at::Tensor trans = at::ones({height, width}, opts);
  at::Tensor last = at::zeros({height, width}, at::kInt);
  AT_DISPATCH_FLOATING_TYPES(colors.scalar_type(), "abcgs_rasterize_forward", [&] {
    GaussianView<scalar_t> gv{means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), colors.data_ptr<scalar_t>(),
                              opacities.data_ptr<scalar_t>(), extents.data_ptr<scalar_t>(), C};
    scalar_t* im = image.data_ptr<scalar_t>();
    scalar_t* tr = trans.data_ptr<scalar_t>();
    int32_t* ls = last.data_ptr<int32_t>();
    for_each_tile(bin.tiles_x * bin.tiles_y,
                  [&](int64_t t) { forward_tile<scalar_t>(gv, bin, t, width, height, tile_size, im, tr, ls); });
  });
  return {image, trans, last, bin.tile_offsets_t, bin.ids_t, bin.gauss_offsets_t, bin.gauss_isect_t};
}

// Returns (v_means2d (N, 2), v_conics (N, 3), v_colors (N, C), v_opacities (N)).
std::vector<at::Tensor> rasterize_backward(const at::Tensor& means2d, const at::Tensor& conics,
                                           const at::Tensor& colors, const at::Tensor& opacities,
                                           const at::Tensor& extents, const at::Tensor& trans,
                                           const at::Tensor& last, const at::Tensor& tile_offsets,
                                           const at::Tensor& ids, const at::Tensor& gauss_offsets,
                                           const at::Tensor& gauss_isect, const at::Tensor& v_image,
                                           const at::Tensor& v_alpha, int64_t width, int64_t height,
                                           int64_t tile_size) {
  check_inputs(means2d, conics, colors, opacities, extents);
  const int64_t n = means2d.size(0), C = colors.size(1), row = 6 + C;
  Binning bin(tile_offsets, ids, gauss_offsets, gauss_isect, width, height, tile_size);
  const int64_t m = bin.num_isects();
  auto opts = colors.options();
  at::Tensor isect_grads = at::zeros({m, row}, opts);
  at::Tensor v_means2d = at::zeros({n, 2}, opts), v_conics = at::zeros({n, 3}, opts);
  at::Tensor v_colors = at::zeros({n, C}, opts), v_opac = at::zeros({n}, opts);
  at::Tensor vi = v_image.contiguous().to(colors.scalar_type());
  at::Tensor va = v_alpha.contiguous().to(colors.scalar_type());
  AT_DISPATCH_FLOATING_TYPES(colors.scalar_type(), "abcgs_rasterize_backward", [&] {
    GaussianView<scalar_t> gv{means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), colors.data_ptr<scalar_t>(),
                              opacities.data_ptr<scalar_t>(), extents.data_ptr<scalar_t>(), C};
    const scalar_t* tr = trans.data_ptr<scalar_t>();
    const int32_t* ls = last.data_ptr<int32_t>();
    const scalar_t* vip = vi.data_ptr<scalar_t>();
    const scalar_t* vap = va.data_ptr<scalar_t>();
    scalar_t* ig = isect_grads.data_ptr<scalar_t>();
    for_each_tile(bin.tiles_x * bin.tiles_y, [&](int64_t t) {
      backward_tile<scalar_t>(gv, bin, t, width, height, tile_size, tr, ls, vip, vap, ig);
    });
    scalar_t* vm = v_means2d.data_ptr<scalar_t>();
    scalar_t* vc = v_conics.data_ptr<scalar_t>();
    scalar_t* vcol = v_colors.data_ptr<scalar_t>();
    scalar_t* vo = v_opac.data_ptr<scalar_t>();
    abcgs::parallel_range(n, 2048, [&](int64_t begin, int64_t end) {
      for (int64_t g = begin; g < end; ++g) {
        for (int64_t j = bin.gauss_offsets[g]; j < bin.gauss_offsets[g + 1]; ++j) {
          const scalar_t* r = ig + bin.gauss_isect[j] * row;
          vm[2 * g] += r[0];
          vm[2 * g + 1] += r[1];
          vc[3 * g] += r[2];
          vc[3 * g + 1] += r[3];
          vc[3 * g + 2] += r[4];
          vo[g] += r[5];
          for (int64_t c = 0; c < C; ++c) vcol[g * C + c] += r[6 + c];
        }
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

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("project_forward", &project_forward, "abcgs fused EWA projection forward (CPU)");
  m.def("project_backward", &project_backward, "abcgs fused EWA projection backward (CPU)");
  m.def("rasterize_forward", &rasterize_forward, "abcgs tile rasterizer forward (CPU)");
  m.def("rasterize_backward", &rasterize_backward, "abcgs tile rasterizer backward (CPU)");
  m.def("pair_dots", &pair_dots, "dot products of selected row pairs of two float32 matrices (CPU)");
  m.def("topk_columns", &topk_columns, "top-k of every column of a row-major matrix, one pass over rows (CPU)");
  m.def("topk_dots_both", &topk_dots_both,
        "the largest dot products of each row of a with the rows of b and vice versa, one pass (CPU)",
        py::arg("a"), py::arg("b"), py::arg("ka"), py::arg("kb"), py::arg("bf16_products") = false);
  m.def("bf16_dot_available", &bf16_dot_available,
        "whether this build has the AVX512-BF16 products of topk_dots_both (a CPU with AVX512-BF16 and AVX512-VL)");
  m.def("rerank_topk", &rerank_topk, "the k candidates with the largest exact dot products, per row (CPU)");
  m.def("l1_ssim_forward", &l1_ssim_forward, "mean L1 and SSIM of two images and their gradients (CPU)");
  m.def("set_kernel_threads", &abcgs::set_kernel_threads, "threads of the CPU kernels (0 = all hardware threads)");
  m.def("kernel_threads", &abcgs::kernel_threads, "threads the CPU kernels use now");
}
