// EWA projection of 3D Gaussians to screen space (forward and hand-written backward), one Gaussian per iteration,
// OpenMP over Gaussians, evaluated in double precision whatever the storage type. Same maths as projection.py
// (which is the reference in the tests):
//   q̂ = q/|q| (identity when |q| <= 1e-12), M_c = V R(q̂) diag(s), p = V μ + t, z = p.z,
//   culled unless near < z < far
//   u = clamp(p.x/z, -lim_x_neg, lim_x_pos), v likewise;
//   rows r_x = fx/z (M_c[0] - u M_c[2]), r_y = fy/z (M_c[1] - v M_c[2])
//   Σ2d = [[|r_x|² + eps, r_x·r_y], [r_x·r_y, |r_y|² + eps]], conic = Σ2d⁻¹ as (a, b, c),
//   means2d = (fx p.x/z + cx, fy p.y/z + cy)
// Culled Gaussians (depth outside (near, far) or det <= 0) get means2d = conic = 0 and no gradient through them.
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace {

constexpr double kQuatEps = 1e-12;
constexpr double kAlphaMin = 1.0 / 255.0;

struct Camera {
  double R[9], t[3];
  double fx, fy, cx, cy;
  double lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos;
  int64_t width, height;
  double near_plane, far_plane, eps2d;

  Camera(const double* view, const double* intr, int64_t w, int64_t h, double near_p, double far_p, double eps) {
    for (int i = 0; i < 9; ++i) R[i] = view[i];
    for (int i = 0; i < 3; ++i) t[i] = view[9 + i];
    fx = intr[0]; fy = intr[1]; cx = intr[2]; cy = intr[3];
    width = w; height = h; near_plane = near_p; far_plane = far_p; eps2d = eps;
    const double tan_x = 0.5 * double(w) / fx, tan_y = 0.5 * double(h) / fy;
    lim_x_pos = (double(w) - cx) / fx + 0.3 * tan_x;
    lim_x_neg = cx / fx + 0.3 * tan_x;
    lim_y_pos = (double(h) - cy) / fy + 0.3 * tan_y;
    lim_y_neg = cy / fy + 0.3 * tan_y;
  }
};

// Everything the backward needs, recomputed from the inputs.
struct Projected {
  bool valid;            // in the depth range and det > 0
  double qn[4], qnorm;   // normalised quaternion and the input norm
  bool q_ok;             // |q| > eps
  double rot[9];         // R(q̂), row-major
  double mc[9];          // V R S, row-major
  double p[3];           // camera-frame mean
  double u, v;           // clamped x/z, y/z
  bool u_free, v_free;   // not clamped
  double rx[3], ry[3];   // rows of J M_c
  double cxx, cxy, cyy, det;
};

template <typename T>
void project_one(const T* mean, const T* quat, const T* scale, const Camera& cam, Projected& o) {
  const double q[4] = {double(quat[0]), double(quat[1]), double(quat[2]), double(quat[3])};
  o.qnorm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  o.q_ok = o.qnorm > kQuatEps;
  for (int i = 0; i < 4; ++i) o.qn[i] = o.q_ok ? q[i] / o.qnorm : (i == 0 ? 1.0 : 0.0);
  const double w = o.qn[0], x = o.qn[1], y = o.qn[2], z = o.qn[3];
  const double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
                       2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                       2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
  for (int i = 0; i < 9; ++i) o.rot[i] = r[i];
  const double s[3] = {double(scale[0]), double(scale[1]), double(scale[2])};
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) {
      double acc = 0;
      for (int j = 0; j < 3; ++j) acc += cam.R[3 * i + j] * r[3 * j + k];
      o.mc[3 * i + k] = acc * s[k];
    }
  for (int i = 0; i < 3; ++i)
    o.p[i] = cam.R[3 * i] * double(mean[0]) + cam.R[3 * i + 1] * double(mean[1]) + cam.R[3 * i + 2] * double(mean[2]) +
             cam.t[i];
  const double zc = o.p[2];
  const bool in_depth = zc > cam.near_plane && zc < cam.far_plane;
  const double zs = in_depth ? zc : 1.0;
  const double ux = o.p[0] / zs, vy = o.p[1] / zs;
  o.u = std::min(std::max(ux, -cam.lim_x_neg), cam.lim_x_pos);
  o.v = std::min(std::max(vy, -cam.lim_y_neg), cam.lim_y_pos);
  o.u_free = ux >= -cam.lim_x_neg && ux <= cam.lim_x_pos;
  o.v_free = vy >= -cam.lim_y_neg && vy <= cam.lim_y_pos;
  for (int k = 0; k < 3; ++k) {
    o.rx[k] = cam.fx / zs * (o.mc[k] - o.u * o.mc[6 + k]);
    o.ry[k] = cam.fy / zs * (o.mc[3 + k] - o.v * o.mc[6 + k]);
  }
  o.cxx = o.rx[0] * o.rx[0] + o.rx[1] * o.rx[1] + o.rx[2] * o.rx[2] + cam.eps2d;
  o.cyy = o.ry[0] * o.ry[0] + o.ry[1] * o.ry[1] + o.ry[2] * o.ry[2] + cam.eps2d;
  o.cxy = o.rx[0] * o.ry[0] + o.rx[1] * o.ry[1] + o.rx[2] * o.ry[2];
  o.det = o.cxx * o.cyy - o.cxy * o.cxy;
  o.valid = in_depth && o.det > 0 && std::isfinite(o.det);
}

template <typename T>
void forward_impl(const T* means, const T* quats, const T* scales, const T* opacities, const double* view,
                  const double* intr, int64_t n, int64_t width, int64_t height, double near_plane, double far_plane,
                  double eps2d, double radius_limit, T* means2d, T* conics, T* depths, T* cov2d, int32_t* radii,
                  int num_threads) {
  const Camera cam(view, intr, width, height, near_plane, far_plane, eps2d);
#pragma omp parallel for num_threads(num_threads) schedule(static)
  for (int64_t i = 0; i < n; ++i) {
    Projected o;
    project_one(means + 3 * i, quats + 4 * i, scales + 3 * i, cam, o);
    depths[i] = T(o.p[2]);
    cov2d[3 * i] = T(o.cxx);
    cov2d[3 * i + 1] = T(o.cxy);
    cov2d[3 * i + 2] = T(o.cyy);
    int32_t rad_x = 0, rad_y = 0;
    if (o.valid) {
      const double mx = cam.fx * o.p[0] / o.p[2] + cam.cx, my = cam.fy * o.p[1] / o.p[2] + cam.cy;
      means2d[2 * i] = T(mx);
      means2d[2 * i + 1] = T(my);
      conics[3 * i] = T(o.cyy / o.det);
      conics[3 * i + 1] = T(-o.cxy / o.det);
      conics[3 * i + 2] = T(o.cxx / o.det);
      const double op = double(opacities[i]);
      if (op > kAlphaMin && std::isfinite(mx) && std::isfinite(my)) {
        const double extent = std::sqrt(std::max(0.0, 2.0 * std::log(op / kAlphaMin)));
        const double rx = std::min(std::ceil(extent * std::sqrt(o.cxx)), radius_limit);
        const double ry = std::min(std::ceil(extent * std::sqrt(o.cyy)), radius_limit);
        const bool inside = mx + rx > 0 && mx - rx < double(width) && my + ry > 0 && my - ry < double(height);
        if (rx > 0 && ry > 0 && inside) {
          rad_x = int32_t(rx);
          rad_y = int32_t(ry);
        }
      }
    } else {
      means2d[2 * i] = means2d[2 * i + 1] = T(0);
      conics[3 * i] = conics[3 * i + 1] = conics[3 * i + 2] = T(0);
    }
    radii[2 * i] = rad_x;
    radii[2 * i + 1] = rad_y;
  }
}

template <typename T>
void backward_impl(const T* means, const T* quats, const T* scales, const double* view, const double* intr,
                   int64_t n, int64_t width, int64_t height, double near_plane, double far_plane, double eps2d,
                   const T* g_means2d, const T* g_conics, const T* g_depths, T* g_means, T* g_quats, T* g_scales,
                   int num_threads) {
  const Camera cam(view, intr, width, height, near_plane, far_plane, eps2d);
#pragma omp parallel for num_threads(num_threads) schedule(static)
  for (int64_t i = 0; i < n; ++i) {
    Projected o;
    project_one(means + 3 * i, quats + 4 * i, scales + 3 * i, cam, o);
    double gp[3] = {0.0, 0.0, double(g_depths[i])};
    double gmc[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    if (o.valid) {
      const double z = o.p[2];
      // conic = (cyy, -cxy, cxx) / det
      const double ga = double(g_conics[3 * i]), gb = double(g_conics[3 * i + 1]), gc = double(g_conics[3 * i + 2]);
      const double s = (ga * o.cyy - gb * o.cxy + gc * o.cxx) / (o.det * o.det);
      const double g_cxx = gc / o.det - s * o.cyy;
      const double g_cyy = ga / o.det - s * o.cxx;
      const double g_cxy = -gb / o.det + 2.0 * s * o.cxy;
      double g_u = 0, g_v = 0, g_z = 0;
      for (int k = 0; k < 3; ++k) {
        const double g_rx = 2.0 * g_cxx * o.rx[k] + g_cxy * o.ry[k];
        const double g_ry = 2.0 * g_cyy * o.ry[k] + g_cxy * o.rx[k];
        gmc[k] += cam.fx / z * g_rx;
        gmc[3 + k] += cam.fy / z * g_ry;
        gmc[6 + k] += -o.u * cam.fx / z * g_rx - o.v * cam.fy / z * g_ry;
        g_u += -cam.fx / z * o.mc[6 + k] * g_rx;
        g_v += -cam.fy / z * o.mc[6 + k] * g_ry;
        g_z += -(o.rx[k] * g_rx + o.ry[k] * g_ry) / z;
      }
      if (o.u_free) {
        gp[0] += g_u / z;
        g_z += -g_u * o.p[0] / (z * z);
      }
      if (o.v_free) {
        gp[1] += g_v / z;
        g_z += -g_v * o.p[1] / (z * z);
      }
      const double gmx = double(g_means2d[2 * i]), gmy = double(g_means2d[2 * i + 1]);
      gp[0] += gmx * cam.fx / z;
      gp[1] += gmy * cam.fy / z;
      g_z += -(gmx * cam.fx * o.p[0] + gmy * cam.fy * o.p[1]) / (z * z);
      gp[2] += g_z;
    }
    // p = V μ + t  →  dμ = Vᵀ dp
    for (int j = 0; j < 3; ++j)
      g_means[3 * i + j] = T(cam.R[j] * gp[0] + cam.R[3 + j] * gp[1] + cam.R[6 + j] * gp[2]);
    // M_c = V M  →  dM = Vᵀ dM_c;  M = R diag(s)  →  dR_jk = dM_jk s_k, ds_k = Σ_j dM_jk R_jk
    double gm[9], gr[9];
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k)
        gm[3 * j + k] = cam.R[j] * gmc[k] + cam.R[3 + j] * gmc[3 + k] + cam.R[6 + j] * gmc[6 + k];
    for (int k = 0; k < 3; ++k) {
      const double sk = double(scales[3 * i + k]);
      double acc = 0;
      for (int j = 0; j < 3; ++j) {
        gr[3 * j + k] = gm[3 * j + k] * sk;
        acc += gm[3 * j + k] * o.rot[3 * j + k];
      }
      g_scales[3 * i + k] = T(acc);
    }
    const double w = o.qn[0], x = o.qn[1], y = o.qn[2], zq = o.qn[3];
    const double gqn[4] = {
        2 * (-zq * gr[1] + y * gr[2] + zq * gr[3] - x * gr[5] - y * gr[6] + x * gr[7]),
        2 * (y * gr[1] + zq * gr[2] + y * gr[3] - 2 * x * gr[4] - w * gr[5] + zq * gr[6] + w * gr[7] - 2 * x * gr[8]),
        2 * (-2 * y * gr[0] + x * gr[1] + w * gr[2] + x * gr[3] + zq * gr[5] - w * gr[6] + zq * gr[7] - 2 * y * gr[8]),
        2 * (-2 * zq * gr[0] - w * gr[1] + x * gr[2] + w * gr[3] - 2 * zq * gr[4] + y * gr[5] + x * gr[6] + y * gr[7]),
    };
    // q̂ = q/|q|  →  dq = (dq̂ - q̂ (q̂·dq̂)) / |q|; zero below the identity threshold
    const double dot = gqn[0] * w + gqn[1] * x + gqn[2] * y + gqn[3] * zq;
    for (int j = 0; j < 4; ++j) g_quats[4 * i + j] = o.q_ok ? T((gqn[j] - o.qn[j] * dot) / o.qnorm) : T(0);
  }
}

}  // namespace

extern "C" {

#define SPOTLESS_DEFINE_PROJECTION(SUFFIX, T)                                                                     \
  void spotless_project_forward_##SUFFIX(const T* means, const T* quats, const T* scales, const T* opacities,     \
                                         const double* view, const double* intr, int64_t n, int64_t width,        \
                                         int64_t height, double near_plane, double far_plane, double eps2d,       \
                                         double radius_limit, T* means2d, T* conics, T* depths, T* cov2d,         \
                                         int32_t* radii, int num_threads) {                                       \
    forward_impl<T>(means, quats, scales, opacities, view, intr, n, width, height, near_plane, far_plane, eps2d,  \
                    radius_limit, means2d, conics, depths, cov2d, radii, num_threads);                            \
  }                                                                                                               \
  void spotless_project_backward_##SUFFIX(const T* means, const T* quats, const T* scales, const double* view,    \
                                          const double* intr, int64_t n, int64_t width, int64_t height,           \
                                          double near_plane, double far_plane, double eps2d, const T* g_means2d,  \
                                          const T* g_conics, const T* g_depths, T* g_means, T* g_quats,           \
                                          T* g_scales, int num_threads) {                                         \
    backward_impl<T>(means, quats, scales, view, intr, n, width, height, near_plane, far_plane, eps2d, g_means2d, \
                     g_conics, g_depths, g_means, g_quats, g_scales, num_threads);                                \
  }

SPOTLESS_DEFINE_PROJECTION(f32, float)
SPOTLESS_DEFINE_PROJECTION(f64, double)

#undef SPOTLESS_DEFINE_PROJECTION
}
