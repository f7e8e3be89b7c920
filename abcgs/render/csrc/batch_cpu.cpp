// Batched cameras for the CPU rasterizer: C views of one size in one call from Python.
//
// The loop over the cameras runs here. Each camera goes through the per-view kernels unchanged (project_forward,
// sh_colors_forward, rasterize_forward and their backward passes, each multi-threaded inside), so every view's
// outputs are bit-identical to a per-view render; they are stacked along a leading camera axis. The gradients of
// the per-Gaussian inputs (means, quats, scales, opacities, SH or shared colours) are summed over the cameras in
// camera order, view 0 first: sum = ((g_0 + g_1) + g_2) + ..., the same sum as adding per-view gradients in that
// order. Within a view, the means' gradient is the projection's plus the SH's, as in the per-view autograd graph.
//
// Included by kernels.cpp after projection_cpu.cpp, rasterize_cpu.cpp and sh_cpu.cpp (one translation unit).

#include "torch_api.h"

#include <vector>

namespace {

// Camera position -R^T t of a (4, 4) world-to-camera matrix, with the ATen ops of
// abcgs.render.rasterize.camera_position (so the per-view path's values, bit for bit).
at::Tensor batch_camera_position(const at::Tensor& viewmat) {
  const at::Tensor rows = viewmat.slice(0, 0, 3);
  const at::Tensor R = rows.slice(1, 0, 3), t = rows.select(1, 3);
  return at::matmul(R.t().neg(), t);
}

void check_cameras(const at::Tensor& viewmats, const at::Tensor& Ks) {
  TORCH_CHECK(viewmats.dim() == 3 && viewmats.size(1) == 4 && viewmats.size(2) == 4, "viewmats must be (C, 4, 4)");
  TORCH_CHECK(Ks.dim() == 3 && Ks.size(1) == 3 && Ks.size(2) == 3, "Ks must be (C, 3, 3)");
  TORCH_CHECK(viewmats.size(0) == Ks.size(0), "viewmats and Ks must have the same number of cameras");
}

// acc = v for the first view, acc += v after: the per-Gaussian sum over the views in camera order
void accumulate(at::Tensor& acc, const at::Tensor& v) {
  if (!acc.defined()) acc = v;
  else acc.add_(v);
}

// The views' tensors along a new leading camera axis; one view is a view of its tensor (no copy: the training
// loops render one camera per step, and a 3 M-Gaussian view's outputs are hundreds of MB).
at::Tensor stack_views(const std::vector<at::Tensor>& views) {
  return views.size() == 1 ? views[0].unsqueeze(0) : at::stack(views);
}

at::Tensor defined_or_empty(const at::Tensor& t, const at::TensorOptions& opts) {
  return t.defined() ? t : at::empty({0}, opts);
}

}  // namespace

// Projection (and, with sh_degree >= 0, SH colours) of N Gaussians into C cameras. Returns (means2d (C, N, 2),
// conics (C, N, 3), depths (C, N), extents (C, N, 2), radii (C, N, 2) int32, visible (C, N) bool, colours (C, N, 3)
// or empty, camera positions (C, 3) or empty). The SH inputs are ignored (may be empty) when sh_degree < 0.
std::vector<at::Tensor> project_batch_forward(const at::Tensor& means, const at::Tensor& quats,
                                              const at::Tensor& scales, const at::Tensor& opacities,
                                              const at::Tensor& viewmats, const at::Tensor& Ks, int64_t width,
                                              int64_t height, double near, double far, double eps2d,
                                              const at::Tensor& sh0, const at::Tensor& shN, int64_t sh_degree) {
  check_cameras(viewmats, Ks);
  const int64_t C = viewmats.size(0);
  std::vector<std::vector<at::Tensor>> outs(8);
  for (int64_t c = 0; c < C; ++c) {
    std::vector<at::Tensor> p =
        project_forward(means, quats, scales, opacities, viewmats[c], Ks[c], width, height, near, far, eps2d);
    if (sh_degree >= 0) {
      at::Tensor campos = batch_camera_position(viewmats[c]).contiguous().to(sh0.scalar_type());
      p.push_back(sh_colors_forward(sh0, shN, means, campos, p[5], sh_degree));
      p.push_back(campos);
    }
    for (size_t k = 0; k < p.size(); ++k) outs[k].push_back(p[k]);
  }
  std::vector<at::Tensor> result;
  for (auto& o : outs) result.push_back(o.empty() ? at::empty({0}, means.options()) : stack_views(o));
  return result;
}

// Backward of project_batch_forward: (v_means (N, 3), v_quats (N, 4), v_scales (N, 3), v_sh0 (N, 1, 3) or empty,
// v_shN or empty), each summed over the cameras in camera order. v_colors may be empty (no colour gradient).
std::vector<at::Tensor> project_batch_backward(const at::Tensor& means, const at::Tensor& quats,
                                               const at::Tensor& scales, const at::Tensor& viewmats,
                                               const at::Tensor& Ks, int64_t width, int64_t height, double near,
                                               double far, double eps2d, const at::Tensor& v_means2d,
                                               const at::Tensor& v_conics, const at::Tensor& v_depths,
                                               const at::Tensor& sh0, const at::Tensor& shN,
                                               const at::Tensor& campos, const at::Tensor& visible,
                                               int64_t sh_degree, const at::Tensor& v_colors, bool need_shN,
                                               bool need_means) {
  check_cameras(viewmats, Ks);
  const int64_t C = viewmats.size(0);
  const bool sh = sh_degree >= 0 && v_colors.numel() > 0;
  at::Tensor v_means, v_quats, v_scales, v_sh0, v_shN;
  for (int64_t c = 0; c < C; ++c) {
    std::vector<at::Tensor> g = project_backward(means, quats, scales, viewmats[c], Ks[c], width, height, near, far,
                                                 eps2d, v_means2d[c], v_conics[c], v_depths[c]);
    at::Tensor vm = g[0];
    if (sh) {
      std::vector<at::Tensor> s = sh_colors_backward(sh0, shN, means, campos[c], visible[c], sh_degree,
                                                     v_colors[c], need_shN, need_means);
      if (need_means) vm = vm + s[2];
      accumulate(v_sh0, s[0]);
      if (need_shN) accumulate(v_shN, s[1]);
    }
    accumulate(v_means, vm);
    accumulate(v_quats, g[1]);
    accumulate(v_scales, g[2]);
  }
  const auto opts = means.options();
  return {v_means, v_quats, v_scales, defined_or_empty(v_sh0, opts), defined_or_empty(v_shN, opts)};
}

// Rasterizes C views: colours (C, N, F) per view or (N, F) shared by all; with depth_channel, each view's depths
// are appended as channel F (RGB+D). Returns (image (C, H, W, F [+ 1]), transmittance (C, H, W), last (C, H, W)
// int32) and, with save, rasterize_forward's eight saved tensors of every view, view by view.
std::vector<at::Tensor> rasterize_batch_forward(const at::Tensor& means2d, const at::Tensor& conics,
                                                const at::Tensor& colors, const at::Tensor& opacities,
                                                const at::Tensor& depths, const at::Tensor& extents, int64_t width,
                                                int64_t height, int64_t tile_size, bool depth_channel, bool save) {
  TORCH_CHECK(means2d.dim() == 3 && means2d.size(2) == 2, "means2d must be (C, N, 2)");
  const int64_t C = means2d.size(0);
  const bool shared = colors.dim() == 2;
  TORCH_CHECK(shared || (colors.dim() == 3 && colors.size(0) == C), "colors must be (N, F) or (C, N, F)");
  std::vector<at::Tensor> images, trans, last, saved;
  for (int64_t c = 0; c < C; ++c) {
    const at::Tensor col = shared ? colors : colors[c];
    std::vector<at::Tensor> r = rasterize_forward(means2d[c], conics[c], col, opacities, depths[c], extents[c],
                                                  width, height, tile_size, depth_channel);
    images.push_back(r[0]);
    trans.push_back(r[1]);
    last.push_back(r[2]);
    if (save) saved.insert(saved.end(), r.begin() + 3, r.end());
  }
  std::vector<at::Tensor> result = {stack_views(images), stack_views(trans), stack_views(last)};
  result.insert(result.end(), saved.begin(), saved.end());
  return result;
}

// Backward of rasterize_batch_forward (saved: its eight tensors per view). Returns (v_means2d (C, N, 2),
// v_conics (C, N, 3), v_colors (like colors: summed over the cameras in camera order when shared), v_opacities (N)
// summed likewise, v_depths (C, N) from the depth channel or empty).
std::vector<at::Tensor> rasterize_batch_backward(const at::Tensor& means2d, const at::Tensor& conics,
                                                 const at::Tensor& colors, const at::Tensor& opacities,
                                                 const at::Tensor& depths, const at::Tensor& extents,
                                                 const at::Tensor& trans, const at::Tensor& last,
                                                 const std::vector<at::Tensor>& saved, const at::Tensor& v_image,
                                                 const at::Tensor& v_alpha, int64_t width, int64_t height,
                                                 int64_t tile_size, bool depth_channel, const at::Tensor& scratch) {
  const int64_t C = means2d.size(0);
  TORCH_CHECK(static_cast<int64_t>(saved.size()) == 8 * C, "rasterize_batch_backward: 8 saved tensors per view");
  const bool shared = colors.dim() == 2;
  const int64_t F = colors.size(-1);
  std::vector<at::Tensor> v_means2d, v_conics, v_colors_views, v_depths;
  at::Tensor v_colors, v_opacities;
  for (int64_t c = 0; c < C; ++c) {
    const at::Tensor col = shared ? colors : colors[c];  // the depth channel is in the saved packed colours
    const at::Tensor* s = saved.data() + 8 * c;
    std::vector<at::Tensor> g =
        rasterize_backward(means2d[c], conics[c], col, opacities, extents[c], trans[c], last[c], s[0], s[1], s[2],
                           s[3], s[4], s[5], s[6], s[7], v_image[c], v_alpha[c], width, height, tile_size, scratch);
    v_means2d.push_back(g[0]);
    v_conics.push_back(g[1]);
    at::Tensor vcol = depth_channel ? g[2].narrow(1, 0, F) : g[2];
    if (depth_channel) v_depths.push_back(g[2].select(1, F));
    if (shared) accumulate(v_colors, depth_channel ? vcol.contiguous() : vcol);
    else v_colors_views.push_back(vcol);
    accumulate(v_opacities, g[3]);
  }
  if (!shared) v_colors = stack_views(v_colors_views);
  return {stack_views(v_means2d), stack_views(v_conics), v_colors, v_opacities,
          depth_channel ? stack_views(v_depths) : at::empty({0}, colors.options())};
}
