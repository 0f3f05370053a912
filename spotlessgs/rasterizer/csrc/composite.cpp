// Tile-based front-to-back alpha compositing of projected 2D Gaussians on the CPU (OpenMP), with a hand-written
// backward pass (back-to-front replay). Plain C ABI, no torch or Python headers: the module is compiled with one g++
// call in about a second and loaded through ctypes (see spotlessgs/rasterizer/composite_cpp.py).
//
// Conventions (shared with composite_torch.py; keep them identical):
//   pixel (x, y) has its centre at (x + 0.5, y + 0.5) in the coordinates of means2d;
//   d = mean - centre, sigma = 0.5 * (a dx^2 + c dy^2) + b dx dy, conic = (a, b, c) = inverse 2D covariance;
//   alpha = min(0.99, opacity * exp(-sigma)); a Gaussian with alpha < 1/255 is skipped at that pixel;
//   compositing stops before the Gaussian that would bring the transmittance T to <= 1e-4 (that one is excluded).
// Arrays are row-major and contiguous. Per-pair gradients are written to slots owned by one tile each and reduced
// serially afterwards, so results do not depend on the number of threads.
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

constexpr double kAlphaMax = 0.99;
constexpr double kAlphaMin = 1.0 / 255.0;
constexpr double kTransmittanceMin = 1e-4;

// Gaussians of one tile gathered into contiguous arrays (structure of arrays) for cache-friendly pixel loops.
template <typename T>
struct TileGaussians {
  std::vector<T> mx, my, a, b, c, op, feat;

  void gather(const T* means2d, const T* conics, const T* opacities, const T* features, const int32_t* ids,
              int64_t begin, int64_t end, int64_t channels) {
    const int64_t n = end - begin;
    mx.resize(n); my.resize(n); a.resize(n); b.resize(n); c.resize(n); op.resize(n);
    feat.resize(n * channels);
    for (int64_t k = 0; k < n; ++k) {
      const int64_t g = ids[begin + k];
      mx[k] = means2d[2 * g];
      my[k] = means2d[2 * g + 1];
      a[k] = conics[3 * g];
      b[k] = conics[3 * g + 1];
      c[k] = conics[3 * g + 2];
      op[k] = opacities[g];
      for (int64_t ch = 0; ch < channels; ++ch) feat[k * channels + ch] = features[g * channels + ch];
    }
  }
};

template <typename T>
void forward_impl(const T* means2d, const T* conics, const T* opacities, const T* features,
                  const int64_t* tile_offsets, const int32_t* gauss_ids, int64_t channels, int64_t width,
                  int64_t height, int64_t tile_size, int64_t tiles_x, int64_t tiles_y, T* out_color,
                  T* out_transmittance, int32_t* out_count, int num_threads) {
  const int64_t n_tiles = tiles_x * tiles_y;
#pragma omp parallel num_threads(num_threads)
  {
    TileGaussians<T> tg;
    std::vector<T> acc(channels);
#pragma omp for schedule(dynamic, 1)
    for (int64_t t = 0; t < n_tiles; ++t) {
      const int64_t begin = tile_offsets[t], end = tile_offsets[t + 1];
      const int64_t n = end - begin;
      tg.gather(means2d, conics, opacities, features, gauss_ids, begin, end, channels);
      const int64_t x0 = (t % tiles_x) * tile_size, y0 = (t / tiles_x) * tile_size;
      const int64_t x1 = std::min(x0 + tile_size, width), y1 = std::min(y0 + tile_size, height);
      for (int64_t py = y0; py < y1; ++py) {
        for (int64_t px = x0; px < x1; ++px) {
          const T cx = T(px) + T(0.5), cy = T(py) + T(0.5);
          std::fill(acc.begin(), acc.end(), T(0));
          T trans = T(1);
          int32_t count = 0;
          for (int64_t k = 0; k < n; ++k) {
            const T dx = tg.mx[k] - cx, dy = tg.my[k] - cy;
            const T sigma = T(0.5) * (tg.a[k] * dx * dx + tg.c[k] * dy * dy) + tg.b[k] * dx * dy;
            const T alpha = std::min(T(kAlphaMax), tg.op[k] * std::exp(-sigma));
            if (alpha < T(kAlphaMin)) continue;
            const T next = trans * (T(1) - alpha);
            if (next <= T(kTransmittanceMin)) break;
            const T w = alpha * trans;
            const T* f = &tg.feat[k * channels];
            for (int64_t ch = 0; ch < channels; ++ch) acc[ch] += w * f[ch];
            trans = next;
            count = int32_t(k + 1);
          }
          const int64_t pix = py * width + px;
          for (int64_t ch = 0; ch < channels; ++ch) out_color[pix * channels + ch] = acc[ch];
          out_transmittance[pix] = trans;
          out_count[pix] = count;
        }
      }
    }
  }
}

// Per-pair gradient layout (stride 6 + C): d mean_x, d mean_y, d conic_a, d conic_b, d conic_c, d opacity, d feat[C].
template <typename T>
void backward_impl(const T* means2d, const T* conics, const T* opacities, const T* features,
                   const int64_t* tile_offsets, const int32_t* gauss_ids, int64_t channels, int64_t width,
                   int64_t height, int64_t tile_size, int64_t tiles_x, int64_t tiles_y, const T* transmittance,
                   const int32_t* counts, const T* grad_color, const T* grad_alpha, T* pair_grads, int num_threads) {
  const int64_t n_tiles = tiles_x * tiles_y;
  const int64_t stride = 6 + channels;
#pragma omp parallel num_threads(num_threads)
  {
    TileGaussians<T> tg;
    std::vector<T> suffix(channels);
#pragma omp for schedule(dynamic, 1)
    for (int64_t t = 0; t < n_tiles; ++t) {
      const int64_t begin = tile_offsets[t], end = tile_offsets[t + 1];
      if (end == begin) continue;
      tg.gather(means2d, conics, opacities, features, gauss_ids, begin, end, channels);
      T* tile_grads = pair_grads + begin * stride;
      const int64_t x0 = (t % tiles_x) * tile_size, y0 = (t / tiles_x) * tile_size;
      const int64_t x1 = std::min(x0 + tile_size, width), y1 = std::min(y0 + tile_size, height);
      for (int64_t py = y0; py < y1; ++py) {
        for (int64_t px = x0; px < x1; ++px) {
          const int64_t pix = py * width + px;
          const int32_t count = counts[pix];
          if (count == 0) continue;
          const T cx = T(px) + T(0.5), cy = T(py) + T(0.5);
          const T* g_col = grad_color + pix * channels;
          const T t_final = transmittance[pix];
          const T g_alpha_final = grad_alpha[pix] * t_final;  // d alpha_out / d alpha_i = T_final / (1 - alpha_i)
          std::fill(suffix.begin(), suffix.end(), T(0));     // sum over later Gaussians of w_j * f_j
          T trans = t_final;
          for (int64_t k = count - 1; k >= 0; --k) {
            const T dx = tg.mx[k] - cx, dy = tg.my[k] - cy;
            const T sigma = T(0.5) * (tg.a[k] * dx * dx + tg.c[k] * dy * dy) + tg.b[k] * dx * dy;
            const T gauss = std::exp(-sigma);
            const T raw = tg.op[k] * gauss;
            const T alpha = std::min(T(kAlphaMax), raw);
            if (alpha < T(kAlphaMin)) continue;
            const T one_minus = T(1) - alpha;
            const T t_before = trans / one_minus;
            const T w = alpha * t_before;
            const T* f = &tg.feat[k * channels];
            T* g = tile_grads + k * stride;
            T dot_f = T(0), dot_s = T(0);
            for (int64_t ch = 0; ch < channels; ++ch) {
              g[6 + ch] += w * g_col[ch];
              dot_f += f[ch] * g_col[ch];
              dot_s += suffix[ch] * g_col[ch];
              suffix[ch] += w * f[ch];
            }
            const T d_alpha = t_before * dot_f - dot_s / one_minus + g_alpha_final / one_minus;
            trans = t_before;
            if (raw > T(kAlphaMax)) continue;  // clamped: alpha does not depend on the parameters
            const T d_sigma = -alpha * d_alpha;
            g[0] += d_sigma * (tg.a[k] * dx + tg.b[k] * dy);
            g[1] += d_sigma * (tg.b[k] * dx + tg.c[k] * dy);
            g[2] += d_sigma * T(0.5) * dx * dx;
            g[3] += d_sigma * dx * dy;
            g[4] += d_sigma * T(0.5) * dy * dy;
            g[5] += gauss * d_alpha;
          }
        }
      }
    }
  }
}

template <typename T>
void reduce_impl(const T* pair_grads, const int32_t* gauss_ids, int64_t n_pairs, int64_t stride, T* out) {
  for (int64_t p = 0; p < n_pairs; ++p) {
    T* dst = out + int64_t(gauss_ids[p]) * stride;
    const T* src = pair_grads + p * stride;
    for (int64_t j = 0; j < stride; ++j) dst[j] += src[j];
  }
}

}  // namespace

extern "C" {

int spotless_raster_abi_version() { return 1; }

#define SPOTLESS_DEFINE(SUFFIX, T)                                                                                  \
  void spotless_composite_forward_##SUFFIX(const T* means2d, const T* conics, const T* opacities,                  \
                                           const T* features, const int64_t* tile_offsets,                         \
                                           const int32_t* gauss_ids, int64_t channels, int64_t width,              \
                                           int64_t height, int64_t tile_size, int64_t tiles_x, int64_t tiles_y,    \
                                           T* out_color, T* out_transmittance, int32_t* out_count,                 \
                                           int num_threads) {                                                      \
    forward_impl<T>(means2d, conics, opacities, features, tile_offsets, gauss_ids, channels, width, height,        \
                    tile_size, tiles_x, tiles_y, out_color, out_transmittance, out_count, num_threads);            \
  }                                                                                                                \
  void spotless_composite_backward_##SUFFIX(                                                                       \
      const T* means2d, const T* conics, const T* opacities, const T* features, const int64_t* tile_offsets,       \
      const int32_t* gauss_ids, int64_t channels, int64_t width, int64_t height, int64_t tile_size,                \
      int64_t tiles_x, int64_t tiles_y, const T* transmittance, const int32_t* counts, const T* grad_color,        \
      const T* grad_alpha, T* pair_grads, int num_threads) {                                                       \
    backward_impl<T>(means2d, conics, opacities, features, tile_offsets, gauss_ids, channels, width, height,       \
                     tile_size, tiles_x, tiles_y, transmittance, counts, grad_color, grad_alpha, pair_grads,       \
                     num_threads);                                                                                 \
  }                                                                                                                \
  void spotless_reduce_pairs_##SUFFIX(const T* pair_grads, const int32_t* gauss_ids, int64_t n_pairs,              \
                                      int64_t stride, T* out) {                                                    \
    reduce_impl<T>(pair_grads, gauss_ids, n_pairs, stride, out);                                                   \
  }

SPOTLESS_DEFINE(f32, float)
SPOTLESS_DEFINE(f64, double)

#undef SPOTLESS_DEFINE
}
