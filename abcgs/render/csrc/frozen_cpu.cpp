// Blending with frozen geometry (CPU): when only the Gaussians' colours change (the colour pass with means,
// scales, rotations and opacities fixed), a view's render is a fixed sparse linear map of the colours,
//   image(p) = sum_i w_i(p) c_i,   w_i(p) = alpha_i(p) T_i(p),
// with the transmittance left behind, T_final(p), fixed too. blend_weights records the map once per view with the
// rasterizer's own binning and blending decisions (rasterize_cpu.cpp: the same alphas, skips and stops, so the
// cached render equals the rasterizer's); frozen_blend_forward / _backward then apply it and its transpose.
//
// Layout: tile-major "runs", one per (tile, Gaussian) pair that blended at least one pixel, in the tile's
// front-to-back order; each run holds its pixels (index inside the 16 x 16 tile, one byte) and weights. A tile
// writes only its own pixels and runs, and a Gaussian's gradient is the sum of its runs in a fixed order
// (tile-major), so results do not depend on the thread count. Included after rasterize_cpu.cpp (one unit).

namespace {

struct TileWeights {
  std::vector<int32_t> run_slot;     // depth rank of each run's Gaussian
  std::vector<int64_t> run_count;    // pixels of each run
  std::vector<uint8_t> entry_pix;    // pixel inside the tile (y * tile_w + x)
  std::vector<float> entry_w;        // its blending weight
};

// One tile's runs: the forward blend of rasterize_cpu.cpp one pixel at a time (the same decisions as the
// vector path), recording w = alpha T for every blend.
template <typename scalar_t>
void weights_tile(const GaussianView<scalar_t>& gv, const Binning& bin, int64_t tile, int64_t width, int64_t height,
                  int64_t tile_size, scalar_t* trans, TileWeights& out) {
  const int64_t tx = tile % bin.tiles_x, ty = tile / bin.tiles_x;
  const int64_t x0 = tx * tile_size, y0 = ty * tile_size;
  const int64_t x1 = std::min(width, x0 + tile_size), y1 = std::min(height, y0 + tile_size);
  const int64_t tw = x1 - x0, th = y1 - y0, npix = tw * th, stride = npix + kRowChunk;
  std::vector<scalar_t> T(stride, scalar_t(1));
  std::vector<uint8_t> done(stride, 0);
  int64_t remaining = npix;
  const int64_t start = bin.tile_offsets[tile], end = bin.tile_offsets[tile + 1];
  for (int64_t k = start; k < end && remaining > 0; ++k) {
    const int64_t slot = bin.slots[k];
    const size_t before = out.entry_w.size();
    for_each_covered_row<false>(gv, slot, x0, x1, y0, y1, tw, AllLanes{},
                                [&](int64_t p0, int64_t, scalar_t, uint32_t mask, const scalar_t* __restrict alpha,
                                    const scalar_t*, const scalar_t*) {
      for (uint32_t m = mask; m != 0; m &= m - 1) {
        const int64_t i = __builtin_ctz(m), p = p0 + i;
        const scalar_t a = alpha[i];
        if (done[p]) continue;
        const scalar_t next_T = T[p] * (scalar_t(1) - a);
        if (next_T <= scalar_t(kTransmittanceEps)) {
          done[p] = 1;
          --remaining;
          continue;
        }
        out.entry_pix.push_back(static_cast<uint8_t>(p));
        out.entry_w.push_back(static_cast<float>(a * T[p]));
        T[p] = next_T;
      }
    });
    if (out.entry_w.size() > before) {
      out.run_slot.push_back(static_cast<int32_t>(slot));
      out.run_count.push_back(static_cast<int64_t>(out.entry_w.size() - before));
    }
  }
  for (int64_t y = y0; y < y1; ++y)
    for (int64_t x = x0; x < x1; ++x) trans[y * width + x] = T[(y - y0) * tw + (x - x0)];
}

void check_frozen(const at::Tensor& tile_runs, const at::Tensor& run_group, const at::Tensor& run_entries,
                  const at::Tensor& entry_pix, const at::Tensor& entry_w, int64_t width, int64_t height,
                  int64_t tile) {
  const int64_t n_tiles = ((width + tile - 1) / tile) * ((height + tile - 1) / tile);
  TORCH_CHECK(tile >= 1 && tile <= 16, "frozen blend: tiles of at most 16 x 16 pixels (a pixel index is one byte)");
  TORCH_CHECK(tile_runs.scalar_type() == at::kLong && tile_runs.numel() == n_tiles + 1 && tile_runs.is_contiguous(),
              "frozen blend: tile_runs must be (n_tiles + 1,) int64");
  TORCH_CHECK(run_group.scalar_type() == at::kInt && run_group.is_contiguous(), "frozen blend: run_group must be int32");
  TORCH_CHECK(run_entries.scalar_type() == at::kLong && run_entries.numel() == run_group.numel() + 1 &&
                  run_entries.is_contiguous(), "frozen blend: run_entries must be (R + 1,) int64");
  TORCH_CHECK(entry_pix.scalar_type() == at::kByte && entry_w.scalar_type() == at::kFloat &&
                  entry_pix.numel() == entry_w.numel() && entry_pix.is_contiguous() && entry_w.is_contiguous(),
              "frozen blend: entries must be (E,) uint8 pixels and (E,) float32 weights");
}

}  // namespace

// The view's map: (trans (H, W), tile_runs (n_tiles + 1) int64, run_slot (R) int32, run_entries (R + 1) int64,
// entry_pix (E) uint8, entry_w (E) float32, order (V) int32) — a run's Gaussian is order[run_slot].
std::vector<at::Tensor> blend_weights(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& opacities,
                                      const at::Tensor& depths, const at::Tensor& extents, int64_t width,
                                      int64_t height, int64_t tile_size) {
  TORCH_CHECK(tile_size >= 1 && tile_size <= 16, "blend_weights: tiles of at most 16 x 16 pixels");
  check_inputs(means2d, conics, opacities.unsqueeze(1).contiguous(), opacities, extents);
  TORCH_CHECK(depths.dim() == 1 && depths.size(0) == means2d.size(0) && depths.is_contiguous() &&
                  depths.scalar_type() == means2d.scalar_type(),
              "depths must be a contiguous (N,) tensor of the means' dtype");
  const int64_t n = means2d.size(0);
  auto opts = means2d.options();
  at::Tensor order = AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "abcgs_weights_order", [&] {
    return depth_order<scalar_t>(depths.data_ptr<scalar_t>(), extents.data_ptr<scalar_t>(), n);
  });
  at::Tensor trans = at::empty({height, width}, opts);
  const int64_t tiles_x = (width + tile_size - 1) / tile_size, tiles_y = (height + tile_size - 1) / tile_size;
  const int64_t n_tiles = tiles_x * tiles_y;
  std::vector<TileWeights> per_tile(static_cast<size_t>(n_tiles));
  at::Tensor no_colors = at::zeros({n, 0}, opts);
  AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "abcgs_blend_weights", [&] {
    const GaussianView<scalar_t> gv(means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                                    no_colors.data_ptr<scalar_t>(), opacities.data_ptr<scalar_t>(),
                                    extents.data_ptr<scalar_t>(), 0, n, order, opts);
    const Binning bin = bin_tiles(gv, order, width, height, tile_size);
    scalar_t* tr = trans.data_ptr<scalar_t>();
    for_each_tile(n_tiles, [&](int64_t t) { weights_tile<scalar_t>(gv, bin, t, width, height, tile_size, tr, per_tile[t]); });
  });
  int64_t n_runs = 0, n_entries = 0;
  for (const auto& t : per_tile) {
    n_runs += static_cast<int64_t>(t.run_slot.size());
    n_entries += static_cast<int64_t>(t.entry_w.size());
  }
  at::Tensor tile_runs = at::empty({n_tiles + 1}, at::kLong), run_slot = at::empty({n_runs}, at::kInt);
  at::Tensor run_entries = at::empty({n_runs + 1}, at::kLong);
  at::Tensor entry_pix = at::empty({n_entries}, at::kByte), entry_w = at::empty({n_entries}, at::kFloat);
  int64_t* tr = tile_runs.data_ptr<int64_t>();
  int32_t* rs = run_slot.data_ptr<int32_t>();
  int64_t* re = run_entries.data_ptr<int64_t>();
  uint8_t* ep = entry_pix.data_ptr<uint8_t>();
  float* ew = entry_w.data_ptr<float>();
  int64_t r = 0, e = 0;
  re[0] = 0;
  for (int64_t t = 0; t < n_tiles; ++t) {
    tr[t] = r;
    auto& tw = per_tile[t];
    std::copy(tw.run_slot.begin(), tw.run_slot.end(), rs + r);
    for (int64_t c : tw.run_count) {
      re[r + 1] = re[r] + c;
      ++r;
    }
    std::copy(tw.entry_pix.begin(), tw.entry_pix.end(), ep + e);
    std::copy(tw.entry_w.begin(), tw.entry_w.end(), ew + e);
    e += static_cast<int64_t>(tw.entry_w.size());
    tw = TileWeights();  // its memory back
  }
  tr[n_tiles] = r;
  return {trans, tile_runs, run_slot, run_entries, entry_pix, entry_w, order};
}

// image (H, W, C) = the map applied to `colors` (G, C) float32, run r reading row run_group[r].
at::Tensor frozen_blend_forward(const at::Tensor& tile_runs, const at::Tensor& run_group, const at::Tensor& run_entries,
                                const at::Tensor& entry_pix, const at::Tensor& entry_w, const at::Tensor& colors,
                                int64_t width, int64_t height, int64_t tile_size) {
  check_frozen(tile_runs, run_group, run_entries, entry_pix, entry_w, width, height, tile_size);
  TORCH_CHECK(colors.scalar_type() == at::kFloat && colors.dim() == 2 && colors.is_contiguous(),
              "frozen blend: colors must be a contiguous (G, C) float32 tensor");
  const int64_t C = colors.size(1), tiles_x = (width + tile_size - 1) / tile_size;
  const int64_t n_tiles = tile_runs.numel() - 1;
  at::Tensor image = at::empty({height, width, C}, colors.options());
  const int64_t* tr = tile_runs.data_ptr<int64_t>();
  const int32_t* rg = run_group.data_ptr<int32_t>();
  const int64_t* re = run_entries.data_ptr<int64_t>();
  const uint8_t* ep = entry_pix.data_ptr<uint8_t>();
  const float* ew = entry_w.data_ptr<float>();
  const float* col = colors.data_ptr<float>();
  float* im = image.data_ptr<float>();
  const int64_t n_groups = colors.size(0);
  for (int64_t r = 0, n_runs = run_group.numel(); r < n_runs; ++r)
    TORCH_CHECK(rg[r] >= 0 && rg[r] < n_groups, "frozen blend: a run's colour row is out of range");
  for_each_tile(n_tiles, [&](int64_t t) {
    const int64_t x0 = (t % tiles_x) * tile_size, y0 = (t / tiles_x) * tile_size;
    const int64_t tw = std::min(width, x0 + tile_size) - x0, th = std::min(height, y0 + tile_size) - y0;
    std::vector<float> acc(static_cast<size_t>(tw * th * C), 0.0f);
    for (int64_t r = tr[t]; r < tr[t + 1]; ++r) {
      const float* c = col + int64_t(rg[r]) * C;
      if (C == 3) {
        const float c0 = c[0], c1 = c[1], c2 = c[2];
        for (int64_t j = re[r]; j < re[r + 1]; ++j) {
          float* a = acc.data() + ep[j] * 3;
          const float w = ew[j];
          a[0] += w * c0;
          a[1] += w * c1;
          a[2] += w * c2;
        }
        continue;
      }
      for (int64_t j = re[r]; j < re[r + 1]; ++j) {
        float* a = acc.data() + ep[j] * C;
        for (int64_t ch = 0; ch < C; ++ch) a[ch] += ew[j] * c[ch];
      }
    }
    for (int64_t y = 0; y < th; ++y)
      std::copy(acc.data() + y * tw * C, acc.data() + (y + 1) * tw * C, im + ((y0 + y) * width + x0) * C);
  });
  return image;
}

// v_colors (G, C) from v_image (H, W, C): each run's sum of w * v_image over its pixels, then each group's runs
// summed in the order `group_runs` lists them (group g: group_runs[group_offsets[g] : group_offsets[g + 1]]).
at::Tensor frozen_blend_backward(const at::Tensor& tile_runs, const at::Tensor& run_group, const at::Tensor& run_entries,
                                 const at::Tensor& entry_pix, const at::Tensor& entry_w, const at::Tensor& group_runs,
                                 const at::Tensor& group_offsets, const at::Tensor& v_image, int64_t width,
                                 int64_t height, int64_t tile_size) {
  check_frozen(tile_runs, run_group, run_entries, entry_pix, entry_w, width, height, tile_size);
  TORCH_CHECK(v_image.scalar_type() == at::kFloat && v_image.dim() == 3 && v_image.size(0) == height &&
                  v_image.size(1) == width && v_image.is_contiguous(),
              "frozen blend: v_image must be a contiguous (H, W, C) float32 tensor");
  TORCH_CHECK(group_runs.scalar_type() == at::kLong && group_runs.numel() == run_group.numel() &&
                  group_offsets.scalar_type() == at::kLong && group_runs.is_contiguous() && group_offsets.is_contiguous(),
              "frozen blend: group_runs (R,) and group_offsets (G + 1,) must be int64");
  const int64_t C = v_image.size(2), tiles_x = (width + tile_size - 1) / tile_size;
  const int64_t n_tiles = tile_runs.numel() - 1, n_runs = run_group.numel(), n_groups = group_offsets.numel() - 1;
  at::Tensor run_grads = at::empty({n_runs, C}, v_image.options());
  at::Tensor v_colors = at::empty({n_groups, C}, v_image.options());
  const int64_t* tr = tile_runs.data_ptr<int64_t>();
  const int64_t* re = run_entries.data_ptr<int64_t>();
  const uint8_t* ep = entry_pix.data_ptr<uint8_t>();
  const float* ew = entry_w.data_ptr<float>();
  const float* vi = v_image.data_ptr<float>();
  float* rgd = run_grads.data_ptr<float>();
  for_each_tile(n_tiles, [&](int64_t t) {
    const int64_t x0 = (t % tiles_x) * tile_size, y0 = (t / tiles_x) * tile_size;
    const int64_t tw = std::min(width, x0 + tile_size) - x0, th = std::min(height, y0 + tile_size) - y0;
    // the tile's gradient image, copied once: a run then reads it by its one-byte pixel index
    std::vector<float> vt(static_cast<size_t>(tw * th * C));
    for (int64_t y = 0; y < th; ++y)
      std::copy(vi + ((y0 + y) * width + x0) * C, vi + ((y0 + y) * width + x0 + tw) * C, vt.data() + y * tw * C);
    for (int64_t r = tr[t]; r < tr[t + 1]; ++r) {
      float* g = rgd + r * C;
      if (C == 3) {
        float g0 = 0.0f, g1 = 0.0f, g2 = 0.0f;
        for (int64_t j = re[r]; j < re[r + 1]; ++j) {
          const float* v = vt.data() + ep[j] * 3;
          const float w = ew[j];
          g0 += w * v[0];
          g1 += w * v[1];
          g2 += w * v[2];
        }
        g[0] = g0;
        g[1] = g1;
        g[2] = g2;
        continue;
      }
      std::fill(g, g + C, 0.0f);
      for (int64_t j = re[r]; j < re[r + 1]; ++j) {
        const float* v = vt.data() + ep[j] * C;
        for (int64_t ch = 0; ch < C; ++ch) g[ch] += ew[j] * v[ch];
      }
    }
  });
  const int64_t* gr = group_runs.data_ptr<int64_t>();
  const int64_t* go = group_offsets.data_ptr<int64_t>();
  float* vc = v_colors.data_ptr<float>();
  abcgs::parallel_range(n_groups, 4096, [&](int64_t begin, int64_t end) {
    for (int64_t g = begin; g < end; ++g) {
      float* out = vc + g * C;
      std::fill(out, out + C, 0.0f);
      for (int64_t j = go[g]; j < go[g + 1]; ++j) {
        const float* r = rgd + gr[j] * C;
        for (int64_t ch = 0; ch < C; ++ch) out[ch] += r[ch];
      }
    }
  });
  return v_colors;
}
