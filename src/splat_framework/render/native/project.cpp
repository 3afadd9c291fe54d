// Native CPU projection and SH colour of 3D Gaussians: forward and hand-derived backward.
//
// The same rules as project_and_shade in _project.py (EWA projection with gsplat's clamped
// Jacobian, eps2d dilation, conics of the dilated covariance, culling by [near, far] and det > 0,
// 3DGS colour max(SH(dir) + 0.5, 0) with dir = unit(mean - camera centre)), one Gaussian at a
// time: no reduction crosses Gaussians, so the result does not depend on the thread count, and
// nothing is traced or compiled at run time (any number of Gaussians, any SH degree). Culled
// Gaussians keep finite values and the gradients the torch version gives them (z replaced by 1
// where it is out of range, det by 1 where it is not positive). The camera is a constant here:
// the Python side uses the torch version when the pose or intrinsics need a gradient.
//
// Shapes: means [N, 3], quats [N, 4] (w, x, y, z, not necessarily normalised), scales [N, 3]
// (activated), colors [N, K, 3] SH coefficients (sh_degree >= 0, K >= (degree + 1)^2) or [N, 3]
// (sh_degree < 0), viewmat [4, 4] world-to-camera, K [3, 3]. Outputs: means2d [N, 2],
// conics [N, 3], cov2d [N, 3], depths [N], valid [N] bool, rgb [N, 3].
#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <cmath>
#include <tuple>

namespace {

constexpr double SH_C0 = 0.28209479177387814;
constexpr double SH_C1 = 0.4886025119029199;
constexpr double SH_C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                             0.5462742152960396};
constexpr double SH_C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                             -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

template <typename T>
struct Cam {
  T W[9];  // world-to-camera rotation, row-major
  T t[3];
  T centre[3];  // camera centre in the world: -W^T t
  T fx, fy, cx, cy;
  T lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg;
  T near_plane, far_plane, eps2d;
};

template <typename T>
Cam<T> make_cam(const torch::Tensor& viewmat, const torch::Tensor& K, int64_t width, int64_t height, double near_plane,
                double far_plane, double eps2d) {
  auto v = viewmat.to(torch::kDouble).contiguous();
  auto k = K.to(torch::kDouble).contiguous();
  const double* vm = v.data_ptr<double>();
  const double* kk = k.data_ptr<double>();
  Cam<T> c;
  for (int r = 0; r < 3; ++r) {
    for (int col = 0; col < 3; ++col) c.W[3 * r + col] = T(vm[4 * r + col]);
    c.t[r] = T(vm[4 * r + 3]);
  }
  for (int i = 0; i < 3; ++i) c.centre[i] = -(c.W[i] * c.t[0] + c.W[3 + i] * c.t[1] + c.W[6 + i] * c.t[2]);
  c.fx = T(kk[0]);
  c.fy = T(kk[4]);
  c.cx = T(kk[2]);
  c.cy = T(kk[5]);
  const T tan_fovx = T(0.5) * T(width) / c.fx;
  const T tan_fovy = T(0.5) * T(height) / c.fy;
  c.lim_x_pos = (T(width) - c.cx) / c.fx + T(0.3) * tan_fovx;
  c.lim_x_neg = c.cx / c.fx + T(0.3) * tan_fovx;
  c.lim_y_pos = (T(height) - c.cy) / c.fy + T(0.3) * tan_fovy;
  c.lim_y_neg = c.cy / c.fy + T(0.3) * tan_fovy;
  c.near_plane = T(near_plane);
  c.far_plane = T(far_plane);
  c.eps2d = T(eps2d);
  return c;
}

// The 16 SH basis functions of a unit direction (3DGS ordering and signs), up to ``degree``.
template <typename T>
inline void sh_basis(int degree, T x, T y, T z, T* b) {
  b[0] = T(SH_C0);
  if (degree < 1) return;
  b[1] = T(-SH_C1) * y;
  b[2] = T(SH_C1) * z;
  b[3] = T(-SH_C1) * x;
  if (degree < 2) return;
  const T xx = x * x, yy = y * y, zz = z * z;
  b[4] = T(SH_C2[0]) * x * y;
  b[5] = T(SH_C2[1]) * y * z;
  b[6] = T(SH_C2[2]) * (T(2) * zz - xx - yy);
  b[7] = T(SH_C2[3]) * x * z;
  b[8] = T(SH_C2[4]) * (xx - yy);
  if (degree < 3) return;
  b[9] = T(SH_C3[0]) * y * (T(3) * xx - yy);
  b[10] = T(SH_C3[1]) * x * y * z;
  b[11] = T(SH_C3[2]) * y * (T(4) * zz - xx - yy);
  b[12] = T(SH_C3[3]) * z * (T(2) * zz - T(3) * xx - T(3) * yy);
  b[13] = T(SH_C3[4]) * x * (T(4) * zz - xx - yy);
  b[14] = T(SH_C3[5]) * z * (xx - yy);
  b[15] = T(SH_C3[6]) * x * (xx - T(3) * yy);
}

// d/d(x, y, z) of sum_k w[k] b_k(x, y, z), added to g.
template <typename T>
inline void sh_basis_vjp(int degree, T x, T y, T z, const T* w, T* g) {
  if (degree < 1) return;
  g[0] += T(-SH_C1) * w[3];
  g[1] += T(-SH_C1) * w[1];
  g[2] += T(SH_C1) * w[2];
  if (degree < 2) return;
  const T xx = x * x, yy = y * y, zz = z * z;
  g[0] += T(SH_C2[0]) * y * w[4] - T(2 * SH_C2[2]) * x * w[6] + T(SH_C2[3]) * z * w[7] + T(2 * SH_C2[4]) * x * w[8];
  g[1] += T(SH_C2[0]) * x * w[4] + T(SH_C2[1]) * z * w[5] - T(2 * SH_C2[2]) * y * w[6] - T(2 * SH_C2[4]) * y * w[8];
  g[2] += T(SH_C2[1]) * y * w[5] + T(4 * SH_C2[2]) * z * w[6] + T(SH_C2[3]) * x * w[7];
  if (degree < 3) return;
  g[0] += T(SH_C3[0]) * T(6) * x * y * w[9] + T(SH_C3[1]) * y * z * w[10] - T(SH_C3[2]) * T(2) * x * y * w[11]
          - T(SH_C3[3]) * T(6) * x * z * w[12] + T(SH_C3[4]) * (T(4) * zz - T(3) * xx - yy) * w[13]
          + T(SH_C3[5]) * T(2) * x * z * w[14] + T(SH_C3[6]) * T(3) * (xx - yy) * w[15];
  g[1] += T(SH_C3[0]) * T(3) * (xx - yy) * w[9] + T(SH_C3[1]) * x * z * w[10]
          + T(SH_C3[2]) * (T(4) * zz - xx - T(3) * yy) * w[11] - T(SH_C3[3]) * T(6) * y * z * w[12]
          - T(SH_C3[4]) * T(2) * x * y * w[13] - T(SH_C3[5]) * T(2) * y * z * w[14] - T(SH_C3[6]) * T(6) * x * y * w[15];
  g[2] += T(SH_C3[1]) * x * y * w[10] + T(SH_C3[2]) * T(8) * y * z * w[11]
          + T(SH_C3[3]) * (T(6) * zz - T(3) * xx - T(3) * yy) * w[12] + T(SH_C3[4]) * T(8) * x * z * w[13]
          + T(SH_C3[5]) * (xx - yy) * w[14];
}

// Everything the forward computes for one Gaussian, kept for its backward.
template <typename T>
struct Geometry {
  T p[3];          // camera-space position
  bool in_range;   // near <= z <= far
  T zs, inv_z;     // z, or 1 out of range
  T u, v;          // x / zs, y / zs before the clamp
  T txz, tyz;      // clamped
  T qn[4];         // normalised quaternion
  T qnorm;
  T R[9];          // rotation of the normalised quaternion
  T A[6];          // J W  [2, 3]
  T Tm[6];         // J W R diag(s)  [2, 3]
  T cxx, cxy, cyy, det;
  bool valid;
};

template <typename T>
inline void geometry(const Cam<T>& c, const T* m, const T* q, const T* s, Geometry<T>& g) {
  for (int r = 0; r < 3; ++r) g.p[r] = c.W[3 * r] * m[0] + c.W[3 * r + 1] * m[1] + c.W[3 * r + 2] * m[2] + c.t[r];
  const T z = g.p[2];
  g.in_range = (z >= c.near_plane) && (z <= c.far_plane);
  g.zs = g.in_range ? z : T(1);
  g.u = g.p[0] / g.zs;
  g.v = g.p[1] / g.zs;
  g.txz = std::min(std::max(g.u, -c.lim_x_neg), c.lim_x_pos);
  g.tyz = std::min(std::max(g.v, -c.lim_y_neg), c.lim_y_pos);
  g.inv_z = T(1) / g.zs;
  const T J00 = c.fx * g.inv_z, J02 = -c.fx * g.txz * g.inv_z;
  const T J11 = c.fy * g.inv_z, J12 = -c.fy * g.tyz * g.inv_z;
  for (int k = 0; k < 3; ++k) {
    g.A[k] = J00 * c.W[k] + J02 * c.W[6 + k];
    g.A[3 + k] = J11 * c.W[3 + k] + J12 * c.W[6 + k];
  }
  g.qnorm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (int k = 0; k < 4; ++k) g.qn[k] = q[k] / g.qnorm;
  const T w = g.qn[0], x = g.qn[1], y = g.qn[2], zq = g.qn[3];
  T* R = g.R;
  R[0] = T(1) - T(2) * (y * y + zq * zq);
  R[1] = T(2) * (x * y - w * zq);
  R[2] = T(2) * (x * zq + w * y);
  R[3] = T(2) * (x * y + w * zq);
  R[4] = T(1) - T(2) * (x * x + zq * zq);
  R[5] = T(2) * (y * zq - w * x);
  R[6] = T(2) * (x * zq - w * y);
  R[7] = T(2) * (y * zq + w * x);
  R[8] = T(1) - T(2) * (x * x + y * y);
  for (int a = 0; a < 2; ++a)
    for (int j = 0; j < 3; ++j)
      g.Tm[3 * a + j] = (g.A[3 * a] * R[j] + g.A[3 * a + 1] * R[3 + j] + g.A[3 * a + 2] * R[6 + j]) * s[j];
  const T* Tm = g.Tm;
  g.cxx = Tm[0] * Tm[0] + Tm[1] * Tm[1] + Tm[2] * Tm[2] + c.eps2d;
  g.cxy = Tm[0] * Tm[3] + Tm[1] * Tm[4] + Tm[2] * Tm[5];
  g.cyy = Tm[3] * Tm[3] + Tm[4] * Tm[4] + Tm[5] * Tm[5] + c.eps2d;
  g.det = g.cxx * g.cyy - g.cxy * g.cxy;
  g.valid = g.in_range && (g.det > T(0));
}

template <typename T>
inline void unit_dir(const Cam<T>& c, const T* m, T* d, T& n) {
  for (int k = 0; k < 3; ++k) d[k] = m[k] - c.centre[k];
  n = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  const T ns = std::max(n, T(1e-12));
  for (int k = 0; k < 3; ++k) d[k] /= ns;
}

// The raw SH expansion (before + 0.5 and the clamp) of coefficients co [K, 3] along the mean's
// unit viewing direction d (its distance to the camera centre in n): raw [3], basis b [16].
template <typename T>
inline void sh_expansion(const Cam<T>& c, int degree, const T* m, const T* co, T* d, T& n, T* b, T* raw) {
  unit_dir(c, m, d, n);
  sh_basis(degree, d[0], d[1], d[2], b);
  const int nb = (degree + 1) * (degree + 1);
  for (int ch = 0; ch < 3; ++ch) {
    T acc = T(0);
    for (int k = 0; k < nb; ++k) acc += b[k] * co[3 * k + ch];
    raw[ch] = acc;
  }
}

template <typename T>
void forward_impl(const Cam<T>& c, int degree, int64_t n, int64_t kcoef, const T* means, const T* quats, const T* scales,
                  const T* colors, T* means2d, T* conics, T* cov2d, T* depths, bool* valid, T* rgb) {
  at::parallel_for(0, n, 512, [&](int64_t begin, int64_t end) {
    Geometry<T> g;
    T b[16];
    for (int64_t i = begin; i < end; ++i) {
      const T* m = means + 3 * i;
      geometry(c, m, quats + 4 * i, scales + 3 * i, g);
      const T ds = g.valid ? g.det : T(1);
      conics[3 * i] = g.cyy / ds;
      conics[3 * i + 1] = -g.cxy / ds;
      conics[3 * i + 2] = g.cxx / ds;
      cov2d[3 * i] = g.cxx;
      cov2d[3 * i + 1] = g.cxy;
      cov2d[3 * i + 2] = g.cyy;
      means2d[2 * i] = c.fx * g.p[0] * g.inv_z + c.cx;
      means2d[2 * i + 1] = c.fy * g.p[1] * g.inv_z + c.cy;
      depths[i] = g.p[2];
      valid[i] = g.valid;
      if (degree < 0) {
        for (int ch = 0; ch < 3; ++ch) rgb[3 * i + ch] = colors[3 * i + ch];
        continue;
      }
      T d[3], nrm, raw[3];
      sh_expansion(c, degree, m, colors + kcoef * 3 * i, d, nrm, b, raw);
      for (int ch = 0; ch < 3; ++ch) rgb[3 * i + ch] = std::max(raw[ch] + T(0.5), T(0));
    }
  });
}

template <typename T>
void backward_impl(const Cam<T>& c, int degree, int64_t n, int64_t kcoef, const T* means, const T* quats,
                   const T* scales, const T* colors, const T* g_means2d, const T* g_conics, const T* g_cov2d,
                   const T* g_depths, const T* g_rgb, T* g_means, T* g_quats, T* g_scales, T* g_colors) {
  at::parallel_for(0, n, 512, [&](int64_t begin, int64_t end) {
    Geometry<T> g;
    T b[16], w[16];
    for (int64_t i = begin; i < end; ++i) {
      const T* m = means + 3 * i;
      const T* s = scales + 3 * i;
      geometry(c, m, quats + 4 * i, s, g);
      // conics = (cyy, -cxy, cxx) / det (det replaced by 1 where the Gaussian is culled)
      const T* gc = g_conics + 3 * i;
      const T ds = g.valid ? g.det : T(1);
      T gxx = gc[2] / ds + g_cov2d[3 * i];
      T gxy = -gc[1] / ds + g_cov2d[3 * i + 1];
      T gyy = gc[0] / ds + g_cov2d[3 * i + 2];
      if (g.valid) {
        const T g_det = -(gc[0] * g.cyy - gc[1] * g.cxy + gc[2] * g.cxx) / (ds * ds);
        gxx += g_det * g.cyy;
        gyy += g_det * g.cxx;
        gxy += g_det * T(-2) * g.cxy;
      }
      // cov = Tm Tm^T (cxx = cov00, cxy = cov01, cyy = cov11)
      const T* Tm = g.Tm;
      T gT[6];
      for (int k = 0; k < 3; ++k) {
        gT[k] = T(2) * gxx * Tm[k] + gxy * Tm[3 + k];
        gT[3 + k] = T(2) * gyy * Tm[3 + k] + gxy * Tm[k];
      }
      // Tm = A M, M = R diag(s): dM = A^T dTm, dA = dTm M^T
      T gM[9], gA[6];
      for (int r = 0; r < 3; ++r)
        for (int j = 0; j < 3; ++j) gM[3 * r + j] = g.A[r] * gT[j] + g.A[3 + r] * gT[3 + j];
      for (int a = 0; a < 2; ++a)
        for (int r = 0; r < 3; ++r) {
          T acc = T(0);
          for (int j = 0; j < 3; ++j) acc += gT[3 * a + j] * g.R[3 * r + j] * s[j];
          gA[3 * a + r] = acc;
        }
      T* gs = g_scales + 3 * i;
      T gR[9];
      for (int j = 0; j < 3; ++j) {
        T acc = T(0);
        for (int r = 0; r < 3; ++r) {
          gR[3 * r + j] = gM[3 * r + j] * s[j];
          acc += gM[3 * r + j] * g.R[3 * r + j];
        }
        gs[j] = acc;
      }
      // R of the normalised quaternion, then the normalisation
      {
        const T w_ = g.qn[0], x = g.qn[1], y = g.qn[2], z = g.qn[3];
        T gq[4];
        gq[0] = T(2) * (-z * gR[1] + y * gR[2] + z * gR[3] - x * gR[5] - y * gR[6] + x * gR[7]);
        gq[1] = T(2) * (y * gR[1] + z * gR[2] + y * gR[3] - T(2) * x * gR[4] - w_ * gR[5] + z * gR[6] + w_ * gR[7]
                        - T(2) * x * gR[8]);
        gq[2] = T(2) * (-T(2) * y * gR[0] + x * gR[1] + w_ * gR[2] + x * gR[3] + z * gR[5] - w_ * gR[6] + z * gR[7]
                        - T(2) * y * gR[8]);
        gq[3] = T(2) * (-T(2) * z * gR[0] - w_ * gR[1] + x * gR[2] + w_ * gR[3] - T(2) * z * gR[4] + y * gR[5]
                        + x * gR[6] + y * gR[7]);
        const T dot = gq[0] * g.qn[0] + gq[1] * g.qn[1] + gq[2] * g.qn[2] + gq[3] * g.qn[3];
        for (int k = 0; k < 4; ++k) g_quats[4 * i + k] = (gq[k] - g.qn[k] * dot) / g.qnorm;
      }
      // A = J W: dJ = dA W^T (only J00, J02, J11, J12 vary)
      T gJ00 = T(0), gJ02 = T(0), gJ11 = T(0), gJ12 = T(0);
      for (int k = 0; k < 3; ++k) {
        gJ00 += gA[k] * c.W[k];
        gJ02 += gA[k] * c.W[6 + k];
        gJ11 += gA[3 + k] * c.W[3 + k];
        gJ12 += gA[3 + k] * c.W[6 + k];
      }
      const T* gm2 = g_means2d + 2 * i;
      T g_inv_z = gJ00 * c.fx - gJ02 * c.fx * g.txz + gJ11 * c.fy - gJ12 * c.fy * g.tyz
                  + gm2[0] * c.fx * g.p[0] + gm2[1] * c.fy * g.p[1];
      const T g_txz = -gJ02 * c.fx * g.inv_z, g_tyz = -gJ12 * c.fy * g.inv_z;
      T gp[3] = {gm2[0] * c.fx * g.inv_z, gm2[1] * c.fy * g.inv_z, g_depths[i]};
      // the clamps pass the gradient strictly inside their limits
      const T g_u = (g.u > -c.lim_x_neg && g.u < c.lim_x_pos) ? g_txz : T(0);
      const T g_v = (g.v > -c.lim_y_neg && g.v < c.lim_y_pos) ? g_tyz : T(0);
      gp[0] += g_u / g.zs;
      gp[1] += g_v / g.zs;
      const T g_zs = -g_inv_z / (g.zs * g.zs) - (g_u * g.p[0] + g_v * g.p[1]) / (g.zs * g.zs);
      if (g.in_range) gp[2] += g_zs;
      T* gmean = g_means + 3 * i;
      for (int k = 0; k < 3; ++k) gmean[k] = c.W[k] * gp[0] + c.W[3 + k] * gp[1] + c.W[6 + k] * gp[2];
      // colour
      const T* gr = g_rgb + 3 * i;
      if (degree < 0) {
        for (int ch = 0; ch < 3; ++ch) g_colors[3 * i + ch] = gr[ch];
        continue;
      }
      T d[3], nrm, raw[3];
      const T* co = colors + kcoef * 3 * i;
      sh_expansion(c, degree, m, co, d, nrm, b, raw);
      const int nb = (degree + 1) * (degree + 1);
      T* gco = g_colors + kcoef * 3 * i;
      T gsh[3];  // the clamp at 0 passes the gradient where it is not active
      for (int ch = 0; ch < 3; ++ch) gsh[ch] = (raw[ch] + T(0.5) >= T(0)) ? gr[ch] : T(0);
      for (int k = 0; k < nb; ++k) {
        w[k] = T(0);
        for (int ch = 0; ch < 3; ++ch) {
          gco[3 * k + ch] = b[k] * gsh[ch];
          w[k] += co[3 * k + ch] * gsh[ch];
        }
      }
      T gd[3] = {T(0), T(0), T(0)};
      sh_basis_vjp(degree, d[0], d[1], d[2], w, gd);
      if (nrm > T(1e-12)) {
        const T dot = gd[0] * d[0] + gd[1] * d[1] + gd[2] * d[2];
        for (int k = 0; k < 3; ++k) gmean[k] += (gd[k] - d[k] * dot) / nrm;
      } else {
        for (int k = 0; k < 3; ++k) gmean[k] += gd[k] / T(1e-12);
      }
    }
  });
}

// Checks the inputs' shapes, device and dtype, and makes them contiguous.
void prepare_inputs(torch::Tensor& means, torch::Tensor& quats, torch::Tensor& scales, torch::Tensor& colors,
                    int64_t sh_degree) {
  const int64_t n = means.size(0);
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "means must be [N, 3]");
  TORCH_CHECK(quats.dim() == 2 && quats.size(0) == n && quats.size(1) == 4, "quats must be [N, 4]");
  TORCH_CHECK(scales.dim() == 2 && scales.size(0) == n && scales.size(1) == 3, "scales must be [N, 3]");
  if (sh_degree < 0) {
    TORCH_CHECK(colors.dim() == 2 && colors.size(0) == n && colors.size(1) == 3, "colors must be [N, 3]");
  } else {
    TORCH_CHECK(sh_degree <= 3, "SH degree must be in 0..3");
    TORCH_CHECK(colors.dim() == 3 && colors.size(0) == n && colors.size(2) == 3 &&
                    colors.size(1) >= (sh_degree + 1) * (sh_degree + 1),
                "colors must be [N, K, 3] with K >= (degree + 1)^2");
  }
  for (const auto* t : {&means, &quats, &scales, &colors}) {
    TORCH_CHECK(t->device().is_cpu(), "the native projection runs on the CPU");
    TORCH_CHECK(t->scalar_type() == means.scalar_type(), "the projection's inputs must share one dtype");
  }
  means = means.contiguous();
  quats = quats.contiguous();
  scales = scales.contiguous();
  colors = colors.contiguous();
}

}  // namespace

std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor> project_forward(
    torch::Tensor means, torch::Tensor quats, torch::Tensor scales, torch::Tensor colors, torch::Tensor viewmat,
    torch::Tensor K, int64_t width, int64_t height, double near_plane, double far_plane, double eps2d,
    int64_t sh_degree) {
  prepare_inputs(means, quats, scales, colors, sh_degree);
  const int64_t n = means.size(0);
  const auto opts = means.options();
  auto means2d = torch::empty({n, 2}, opts);
  auto conics = torch::empty({n, 3}, opts);
  auto cov2d = torch::empty({n, 3}, opts);
  auto depths = torch::empty({n}, opts);
  auto valid = torch::empty({n}, opts.dtype(torch::kBool));
  auto rgb = torch::empty({n, 3}, opts);
  const int64_t kcoef = sh_degree < 0 ? 1 : colors.size(1);
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_forward", [&] {
    const auto cam = make_cam<scalar_t>(viewmat, K, width, height, near_plane, far_plane, eps2d);
    forward_impl<scalar_t>(cam, int(sh_degree), n, kcoef, means.data_ptr<scalar_t>(), quats.data_ptr<scalar_t>(),
                           scales.data_ptr<scalar_t>(), colors.data_ptr<scalar_t>(), means2d.data_ptr<scalar_t>(),
                           conics.data_ptr<scalar_t>(), cov2d.data_ptr<scalar_t>(), depths.data_ptr<scalar_t>(),
                           valid.data_ptr<bool>(), rgb.data_ptr<scalar_t>());
  });
  return {means2d, conics, cov2d, depths, valid, rgb};
}

std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor> project_backward(
    torch::Tensor means, torch::Tensor quats, torch::Tensor scales, torch::Tensor colors, torch::Tensor viewmat,
    torch::Tensor K, int64_t width, int64_t height, double near_plane, double far_plane, double eps2d,
    int64_t sh_degree, torch::Tensor g_means2d, torch::Tensor g_conics, torch::Tensor g_cov2d, torch::Tensor g_depths,
    torch::Tensor g_rgb) {
  prepare_inputs(means, quats, scales, colors, sh_degree);
  const int64_t n = means.size(0);
  const auto dt = means.scalar_type();
  g_means2d = g_means2d.to(dt).contiguous();
  g_conics = g_conics.to(dt).contiguous();
  g_cov2d = g_cov2d.to(dt).contiguous();
  g_depths = g_depths.to(dt).contiguous();
  g_rgb = g_rgb.to(dt).contiguous();
  TORCH_CHECK(g_means2d.numel() == 2 * n && g_conics.numel() == 3 * n && g_cov2d.numel() == 3 * n &&
                  g_depths.numel() == n && g_rgb.numel() == 3 * n,
              "the projection's output gradients do not match its N");
  auto g_means = torch::empty_like(means);
  auto g_quats = torch::empty_like(quats);
  auto g_scales = torch::empty_like(scales);
  auto g_colors = torch::zeros_like(colors);  // bands above the degree get no gradient
  const int64_t kcoef = sh_degree < 0 ? 1 : colors.size(1);
  AT_DISPATCH_FLOATING_TYPES(dt, "project_backward", [&] {
    const auto cam = make_cam<scalar_t>(viewmat, K, width, height, near_plane, far_plane, eps2d);
    backward_impl<scalar_t>(cam, int(sh_degree), n, kcoef, means.data_ptr<scalar_t>(), quats.data_ptr<scalar_t>(),
                            scales.data_ptr<scalar_t>(), colors.data_ptr<scalar_t>(), g_means2d.data_ptr<scalar_t>(),
                            g_conics.data_ptr<scalar_t>(), g_cov2d.data_ptr<scalar_t>(), g_depths.data_ptr<scalar_t>(),
                            g_rgb.data_ptr<scalar_t>(), g_means.data_ptr<scalar_t>(), g_quats.data_ptr<scalar_t>(),
                            g_scales.data_ptr<scalar_t>(), g_colors.data_ptr<scalar_t>());
  });
  return {g_means, g_quats, g_scales, g_colors};
}
