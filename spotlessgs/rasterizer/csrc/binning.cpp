// Tile binning (same result as binning.py, exactly): visible Gaussians sorted front to back (stable, so equal depths
// keep index order), then listed once per tile that their bounding box overlaps, grouped by tile in row-major order.
// Two passes so that Python can allocate the pair array: spotless_bin_count_* sorts and counts, spotless_bin_fill
// writes the pairs.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

struct TileRect {
  int64_t x0, x1, y0, y1;  // inclusive tile index ranges
};

template <typename T>
TileRect tile_rect(const T* means2d, const int32_t* radii, int64_t g, int64_t tile_size, int64_t tiles_x,
                   int64_t tiles_y) {
  const double mx = double(means2d[2 * g]), my = double(means2d[2 * g + 1]);
  const double rx = double(radii[2 * g]), ry = double(radii[2 * g + 1]);
  const double ts = double(tile_size);
  auto clampi = [](double v, int64_t hi) { return int64_t(std::min(std::max(v, 0.0), double(hi))); };
  return TileRect{clampi(std::floor((mx - rx) / ts), tiles_x - 1), clampi(std::floor((mx + rx) / ts), tiles_x - 1),
                  clampi(std::floor((my - ry) / ts), tiles_y - 1), clampi(std::floor((my + ry) / ts), tiles_y - 1)};
}

template <typename T>
int64_t count_impl(const T* means2d, const int32_t* radii, const T* depths, int64_t n, int64_t tile_size,
                   int64_t tiles_x, int64_t tiles_y, int32_t* order, int64_t* tile_counts) {
  int64_t visible = 0;
  for (int64_t g = 0; g < n; ++g)
    if (radii[2 * g] > 0 && radii[2 * g + 1] > 0) order[visible++] = int32_t(g);
  std::stable_sort(order, order + visible,
                   [depths](int32_t i, int32_t j) { return double(depths[i]) < double(depths[j]); });
  std::fill(tile_counts, tile_counts + tiles_x * tiles_y, int64_t(0));
  for (int64_t v = 0; v < visible; ++v) {
    const TileRect r = tile_rect(means2d, radii, order[v], tile_size, tiles_x, tiles_y);
    for (int64_t ty = r.y0; ty <= r.y1; ++ty)
      for (int64_t tx = r.x0; tx <= r.x1; ++tx) ++tile_counts[ty * tiles_x + tx];
  }
  return visible;
}

template <typename T>
void fill_impl(const T* means2d, const int32_t* radii, const int32_t* order, int64_t visible, int64_t tile_size,
               int64_t tiles_x, int64_t tiles_y, const int64_t* tile_offsets, int32_t* gauss_ids) {
  std::vector<int64_t> cursor(tile_offsets, tile_offsets + tiles_x * tiles_y);
  for (int64_t v = 0; v < visible; ++v) {
    const int32_t g = order[v];
    const TileRect r = tile_rect(means2d, radii, g, tile_size, tiles_x, tiles_y);
    for (int64_t ty = r.y0; ty <= r.y1; ++ty)
      for (int64_t tx = r.x0; tx <= r.x1; ++tx) gauss_ids[cursor[ty * tiles_x + tx]++] = g;
  }
}

}  // namespace

extern "C" {

#define SPOTLESS_DEFINE_BINNING(SUFFIX, T)                                                                        \
  int64_t spotless_bin_count_##SUFFIX(const T* means2d, const int32_t* radii, const T* depths, int64_t n,         \
                                      int64_t tile_size, int64_t tiles_x, int64_t tiles_y, int32_t* order,        \
                                      int64_t* tile_counts) {                                                     \
    return count_impl<T>(means2d, radii, depths, n, tile_size, tiles_x, tiles_y, order, tile_counts);             \
  }                                                                                                               \
  void spotless_bin_fill_##SUFFIX(const T* means2d, const int32_t* radii, const int32_t* order, int64_t visible,  \
                                  int64_t tile_size, int64_t tiles_x, int64_t tiles_y, const int64_t* tile_offsets, \
                                  int32_t* gauss_ids) {                                                           \
    fill_impl<T>(means2d, radii, order, visible, tile_size, tiles_x, tiles_y, tile_offsets, gauss_ids);           \
  }

SPOTLESS_DEFINE_BINNING(f32, float)
SPOTLESS_DEFINE_BINNING(f64, double)

#undef SPOTLESS_DEFINE_BINNING
}
