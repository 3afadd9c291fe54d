// Native CPU compositing of one depth chunk: forward and hand-derived backward.
//
// The same rules and the same closed-form backward as the per-round torch kernels of
// _kernels.py (alpha = min(o exp(-q/2), 0.99), alphas below 1/255 skipped, a pair is
// included while T (1 - alpha) >= 1e-4, pixel centres at +0.5), walked the way the
// 3DGS reference walks a tile: every pair of a tile's list in depth order against
// the tile's pixels, the transmittance kept in registers, the tile dropped once all
// its pixels stopped. Tiles run in parallel on torch's intra-op threads (so the
// process's thread policy applies), handed out one at a time (tiles differ a lot in
// work). The pixel loops are plain arithmetic (exp by range reduction and a
// polynomial in float) so the compiler vectorises them.
//
// Shapes (T tiles, P = tile * tile pixels, R = 6 + F table columns, F = 5 features):
//   table     [N + 1, R]  (u, v, a, b, c, log o | r, g, b, z, 1), q = a dx^2 + 2 b dx dy + c dy^2
//   gid       [Pc]        the chunk's Gaussian rows, sorted by (tile, depth)
//   offset    [T]         first position of each tile's list in gid
//   count     [T]         length of each tile's list
//   active    [A]         the tiles with pairs in this chunk
//   centers   [T, 2]      tile centres in pixels
//   t_state   [T, P]      transmittance (0 = the pixel stopped); updated in place
//   out       [T, F, P]   sum of w f; updated in place
//   n_incl    [A, P]      (returned) pairs of the tile's list each pixel included
#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

namespace {

constexpr int F = 5;
constexpr int R = 6 + F;
constexpr double ALPHA_MIN = 1.0 / 255.0;
constexpr double ALPHA_MAX = 0.99;
constexpr double T_MIN = 1e-4;

// exp(x) for x <= log(0.99): 2^-n p(r) with n = round(-x / ln 2) in [0, 15] (x is clamped at
// -10, where o exp(-q/2) <= exp(-10) is far below 1/255 and the pair is skipped anyway) and a
// degree-7 polynomial on |r| <= ln(2) / 2 (relative error about 1e-7). Branch-free; 2^-n is the
// float whose exponent field is 127 - n (a normal number for n <= 15), so the product is exact
// and the same bits as multiplying by 2^-8, 2^-4, 2^-2, 2^-1 in turn, in a quarter of the
// instructions (the forward's pixel loop ran 10 % faster).
inline float exp_neg(float x) {
  x = std::max(x, -10.0f);
  const int ni = int(-x * 1.44269504088896341f + 0.5f);  // x <= 0: truncation rounds
  const float n = float(ni);
  const float r = x + n * 0.693145751953125f + n * 1.42860682030941723212e-6f;
  float p = 1.0f / 5040.0f;
  p = p * r + 1.0f / 720.0f;
  p = p * r + 1.0f / 120.0f;
  p = p * r + 1.0f / 24.0f;
  p = p * r + 1.0f / 6.0f;
  p = p * r + 0.5f;
  p = p * r + 1.0f;
  p = p * r + 1.0f;
  const int32_t bits = (127 - ni) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof(scale));
  return p * scale;
}

inline double exp_neg(double x) { return std::exp(x); }

// log(o G) and alpha of the Gaussian (u, v, a, b, c, log o) at the pixel offset (dx, dy) from its
// mean: alpha = min(o G, 0.99), 0 below 1/255. Forward and backward call this one function, so
// they agree on every alpha.
template <typename scalar_t>
inline scalar_t pixel_alpha(scalar_t dx, scalar_t dy, scalar_t a, scalar_t b, scalar_t c, scalar_t lo,
                            scalar_t amin, scalar_t lmax, scalar_t& logit) {
  logit = lo - scalar_t(0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy;
  const scalar_t alpha = exp_neg(std::min(logit, lmax));
  return alpha < amin ? scalar_t(0) : alpha;
}

// Pixel centres (px, py) [P] of tile t, row-major, from the tile centres [T, 2].
template <typename scalar_t>
void tile_pixels(const scalar_t* centers, int64_t t, int tile, scalar_t* px, scalar_t* py) {
  const scalar_t half = scalar_t(tile) / scalar_t(2) - scalar_t(0.5);
  for (int i = 0; i < tile * tile; ++i) {
    px[i] = centers[2 * t] + scalar_t(i % tile) - half;
    py[i] = centers[2 * t + 1] + scalar_t(i / tile) - half;
  }
}

// Run work(tile_index_in_active, slot) for every active tile on torch's intra-op threads (the
// count the process's thread policy sets); ``slot`` < slots is unique among the concurrent
// workers. Dynamic: tiles handed out one at a time (tiles differ a lot in work). Fixed: slot s
// takes tiles s, s + slots, ... (neighbouring tiles cost about the same), so what each slot adds
// up, and in which order, does not depend on timing: the backward's sums are deterministic.
// Built with -fopenmp, the extension's OpenMP calls go to the libgomp that torch already loaded
// (same soname): one thread pool, no second runtime.
template <typename Fn>
void for_each_tile(int64_t n_active, int64_t slots, bool fixed, const Fn& work) {
  std::atomic<int64_t> next{0};
  at::parallel_for(0, slots, 1, [&](int64_t begin, int64_t end) {
    for (int64_t slot = begin; slot < end; ++slot) {
      if (fixed) {
        for (int64_t i = slot; i < n_active; i += slots) work(i, slot);
      } else {
        for (int64_t i = next.fetch_add(1); i < n_active; i = next.fetch_add(1)) work(i, slot);
      }
    }
  });
}

// One pair against a tile's P pixels: alpha, inclusion, the weighted features added to acc
// [F, P], T updated (0 once a pixel stops), inc counting included pairs; returns the number of
// pixels that included it (0: every pixel of the tile has stopped).
template <typename scalar_t>
int forward_pair(const scalar_t* row, const scalar_t* __restrict px, const scalar_t* __restrict py,
                 scalar_t* __restrict T, scalar_t* __restrict acc, int32_t* __restrict inc, const int P,
                 const scalar_t amin, const scalar_t lmax, const scalar_t tmin) {
  const scalar_t u = row[0], v = row[1], a = row[2], b = row[3], c = row[4], lo = row[5];
  const scalar_t f0 = row[6], f1 = row[7], f2 = row[8], f3 = row[9], f4 = row[10];
  scalar_t* __restrict a0 = acc;
  scalar_t* __restrict a1 = acc + P;
  scalar_t* __restrict a2 = acc + 2 * P;
  scalar_t* __restrict a3 = acc + 3 * P;
  scalar_t* __restrict a4 = acc + 4 * P;
  int alive = 0;
#pragma omp simd reduction(+ : alive)
  for (int i = 0; i < P; ++i) {
    const scalar_t dx = px[i] - u, dy = py[i] - v;
    scalar_t logit;
    const scalar_t alpha = pixel_alpha(dx, dy, a, b, c, lo, amin, lmax, logit);
    const scalar_t tb = T[i];
    const scalar_t ta = tb * (scalar_t(1) - alpha);
    const int in = ta >= tmin ? 1 : 0;
    const scalar_t w = in ? alpha * tb : scalar_t(0);
    a0[i] += w * f0;
    a1[i] += w * f1;
    a2[i] += w * f2;
    a3[i] += w * f3;
    a4[i] += w * f4;
    inc[i] += in;
    T[i] = in ? ta : scalar_t(0);  // a stopped pixel holds 0 (never a denormal)
    alive += in;
  }
  return alive;
}

template <typename scalar_t>
void forward_impl(const torch::Tensor& table, const torch::Tensor& gid, const torch::Tensor& offset,
                  const torch::Tensor& count, const torch::Tensor& active, const torch::Tensor& centers,
                  torch::Tensor& t_state, torch::Tensor& out, torch::Tensor& n_incl, int tile) {
  const int P = tile * tile;
  const scalar_t* tab = table.data_ptr<scalar_t>();
  const int64_t* g = gid.data_ptr<int64_t>();
  const int64_t* off = offset.data_ptr<int64_t>();
  const int64_t* cnt = count.data_ptr<int64_t>();
  const int64_t* act = active.data_ptr<int64_t>();
  const scalar_t* ctr = centers.data_ptr<scalar_t>();
  scalar_t* ts = t_state.data_ptr<scalar_t>();
  scalar_t* o = out.data_ptr<scalar_t>();
  int32_t* ninc = n_incl.data_ptr<int32_t>();
  const scalar_t amin = scalar_t(ALPHA_MIN), lmax = std::log(scalar_t(ALPHA_MAX)), tmin = scalar_t(T_MIN);
  const int64_t slots = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), active.size(0) / 4 + 1));
  for_each_tile(active.size(0), slots, false, [&](int64_t ai, int64_t) {
    const int64_t t = act[ai];
    std::vector<scalar_t> px(P), py(P), acc(F * P);
    std::vector<int32_t> inc(P, 0);
    scalar_t* T = ts + t * P;
    tile_pixels(ctr, t, tile, px.data(), py.data());
    std::copy(o + t * F * P, o + (t + 1) * F * P, acc.begin());
    const int64_t* list = g + off[t];
    const int64_t n = cnt[t];
    for (int64_t k = 0; k < n; ++k) {
      if (k + 4 < n) __builtin_prefetch(tab + list[k + 4] * R);  // rows are in depth order, not memory order
      const scalar_t* row = tab + list[k] * R;
      if (forward_pair(row, px.data(), py.data(), T, acc.data(), inc.data(), P, amin, lmax, tmin) == 0) break;
    }
    for (int i = 0; i < P; ++i) ninc[ai * P + i] = inc[i];
    std::copy(acc.begin(), acc.end(), o + t * F * P);
  });
}

// The backward of one pair (the k-th of its tile's list) against the tile's P pixels, front
// to back: T and the running sum cs = prefix + sum w h move past the pair; the pair's
// gradients (u, v, a, b, c, log o | features) are added to dst [R], and with ABS also the sums
// over the pixels of each pixel's |dL/du|, |dL/dv| to dst[R], dst[R + 1] (AbsGS's criterion).
template <typename scalar_t, bool ABS>
void backward_pair(const scalar_t* row, const int32_t k, const scalar_t* __restrict px,
                   const scalar_t* __restrict py, scalar_t* __restrict T, scalar_t* __restrict cs,
                   const scalar_t* __restrict tt, const int32_t* __restrict inc, const scalar_t* __restrict gv,
                   const int P, const scalar_t amin, const scalar_t lmax, scalar_t* dst) {
  const scalar_t u = row[0], v = row[1], a = row[2], b = row[3], c = row[4], lo = row[5];
  const scalar_t f0 = row[6], f1 = row[7], f2 = row[8], f3 = row[9], f4 = row[10];
  const scalar_t* __restrict g0 = gv;
  const scalar_t* __restrict g1 = gv + P;
  const scalar_t* __restrict g2 = gv + 2 * P;
  const scalar_t* __restrict g3 = gv + 3 * P;
  const scalar_t* __restrict g4 = gv + 4 * P;
  scalar_t s_lo = 0, s_a = 0, s_b = 0, s_c = 0, s_u = 0, s_v = 0;
  scalar_t w0 = 0, w1 = 0, w2 = 0, w3 = 0, w4 = 0, abs_u = 0, abs_v = 0;
#pragma omp simd reduction(+ : s_lo, s_a, s_b, s_c, s_u, s_v, w0, w1, w2, w3, w4, abs_u, abs_v)
  for (int i = 0; i < P; ++i) {
    const scalar_t dx = px[i] - u, dy = py[i] - v;
    scalar_t logit;
    const scalar_t alpha = pixel_alpha(dx, dy, a, b, c, lo, amin, lmax, logit);
    const scalar_t om = scalar_t(1) - alpha;
    const scalar_t tb = T[i];
    const bool in = k < inc[i];
    const scalar_t w = in ? alpha * tb : scalar_t(0);
    const scalar_t h = f0 * g0[i] + f1 * g1[i] + f2 * g2[i] + f3 * g3[i] + f4 * g4[i];
    const scalar_t csi = cs[i] + w * h;
    cs[i] = csi;
    // dL/dlogit = alpha (T h - S / (1 - alpha)), S = total - prefix through this pair
    const scalar_t dp = (in && logit < lmax) ? alpha * (tb * h - (tt[i] - csi) / om) : scalar_t(0);
    T[i] = in ? tb * om : scalar_t(0);
    s_lo += dp;
    s_a += dp * dx * dx;
    s_b += dp * dx * dy;
    s_c += dp * dy * dy;
    const scalar_t du = dp * (a * dx + b * dy), dv = dp * (b * dx + c * dy);
    s_u += du;
    s_v += dv;
    if (ABS) {
      abs_u += std::abs(du);
      abs_v += std::abs(dv);
    }
    w0 += w * g0[i];
    w1 += w * g1[i];
    w2 += w * g2[i];
    w3 += w * g3[i];
    w4 += w * g4[i];
  }
  dst[0] += s_u;
  dst[1] += s_v;
  dst[2] += scalar_t(-0.5) * s_a;
  dst[3] += -s_b;
  dst[4] += scalar_t(-0.5) * s_c;
  dst[5] += s_lo;
  dst[6] += w0;
  dst[7] += w1;
  dst[8] += w2;
  dst[9] += w3;
  dst[10] += w4;
  if (ABS) {
    dst[R] += abs_u;
    dst[R + 1] += abs_v;
  }
}

template <typename scalar_t>
void backward_impl(const torch::Tensor& table, const torch::Tensor& gid, const torch::Tensor& offset,
                   const torch::Tensor& active, const torch::Tensor& centers, const torch::Tensor& t_entry,
                   const torch::Tensor& n_incl, const torch::Tensor& g_out, const torch::Tensor& total,
                   torch::Tensor& prefix, torch::Tensor& grads, int tile) {
  const int P = tile * tile;
  const scalar_t* tab = table.data_ptr<scalar_t>();
  const int64_t rows = table.size(0);
  const int64_t* g = gid.data_ptr<int64_t>();
  const int64_t* off = offset.data_ptr<int64_t>();
  const int64_t* act = active.data_ptr<int64_t>();
  const scalar_t* ctr = centers.data_ptr<scalar_t>();
  const scalar_t* te = t_entry.data_ptr<scalar_t>();
  const int32_t* ninc = n_incl.data_ptr<int32_t>();
  const scalar_t* go = g_out.data_ptr<scalar_t>();
  const scalar_t* tot = total.data_ptr<scalar_t>();
  scalar_t* pre = prefix.data_ptr<scalar_t>();
  scalar_t* gr = grads.data_ptr<scalar_t>();
  const scalar_t amin = scalar_t(ALPHA_MIN), lmax = std::log(scalar_t(ALPHA_MAX));
  const int64_t W = grads.size(2);  // R, or R + 2 with the absolute-gradient sums
  const bool with_abs = W == R + 2;
  // every slot of grads is used, whatever the chunk's size: the sums depend only on the slot count
  for_each_tile(active.size(0), grads.size(0), true, [&](int64_t ai, int64_t slot) {
    const int64_t t = act[ai];
    std::vector<scalar_t> px(P), py(P), T(P), cs(P), gv(F * P), tt(P);
    std::vector<int32_t> inc(P);
    int32_t n_max = 0;
    tile_pixels(ctr, t, tile, px.data(), py.data());
    for (int i = 0; i < P; ++i) {
      T[i] = te[ai * P + i];
      cs[i] = pre[t * P + i];
      tt[i] = tot[t * P + i];
      inc[i] = ninc[ai * P + i];
      n_max = std::max(n_max, inc[i]);
    }
    std::copy(go + t * F * P, go + (t + 1) * F * P, gv.begin());
    scalar_t* slot_grads = gr + slot * rows * W;
    const int64_t* list = g + off[t];
    for (int32_t k = 0; k < n_max; ++k) {
      if (k + 4 < n_max) {
        __builtin_prefetch(tab + list[k + 4] * R);
        __builtin_prefetch(slot_grads + list[k + 4] * W, 1);
      }
      const int64_t id = list[k];
      const scalar_t* row = tab + id * R;
      if (with_abs)
        backward_pair<scalar_t, true>(row, k, px.data(), py.data(), T.data(), cs.data(), tt.data(), inc.data(),
                                      gv.data(), P, amin, lmax, slot_grads + id * W);
      else
        backward_pair<scalar_t, false>(row, k, px.data(), py.data(), T.data(), cs.data(), tt.data(), inc.data(),
                                       gv.data(), P, amin, lmax, slot_grads + id * W);
    }
    for (int i = 0; i < P; ++i) pre[t * P + i] = cs[i];
  });
}

void check(const torch::Tensor& table, int tile) {
  TORCH_CHECK(table.device().is_cpu(), "native compositing runs on CPU tensors");
  TORCH_CHECK(table.dim() == 2 && table.size(1) == R, "table must be [N + 1, ", R, "]");
  TORCH_CHECK(tile > 0 && tile <= 64, "tile must be in [1, 64]");
}

}  // namespace

// (t_state, out updated in place) -> n_incl [A, P] int32
torch::Tensor composite_forward(torch::Tensor table, torch::Tensor gid, torch::Tensor offset, torch::Tensor count,
                                torch::Tensor active, torch::Tensor centers, torch::Tensor t_state,
                                torch::Tensor out, int64_t tile) {
  check(table, tile);
  TORCH_CHECK(t_state.is_contiguous() && out.is_contiguous(), "t_state and out must be contiguous");
  auto n_incl = torch::zeros({active.size(0), tile * tile}, table.options().dtype(torch::kInt32));
  AT_DISPATCH_FLOATING_TYPES(table.scalar_type(), "composite_forward", [&] {
    forward_impl<scalar_t>(table.contiguous(), gid.contiguous(), offset.contiguous(), count.contiguous(),
                           active.contiguous(), centers.contiguous(), t_state, out, n_incl, int(tile));
  });
  return n_incl;
}

// (prefix [T, P] and grads [slots, N + 1, R] or [slots, N + 1, R + 2] updated in place; the two extra
// columns: per Gaussian, the sums over pixels of |dL/du| and |dL/dv|)
void composite_backward(torch::Tensor table, torch::Tensor gid, torch::Tensor offset, torch::Tensor active,
                        torch::Tensor centers, torch::Tensor t_entry, torch::Tensor n_incl, torch::Tensor g_out,
                        torch::Tensor total, torch::Tensor prefix, torch::Tensor grads, int64_t tile) {
  check(table, tile);
  TORCH_CHECK(prefix.is_contiguous() && grads.is_contiguous(), "prefix and grads must be contiguous");
  TORCH_CHECK(grads.dim() == 3 && (grads.size(2) == R || grads.size(2) == R + 2),
              "grads must be [slots, N + 1, ", R, "] or, with the absolute-gradient sums, [slots, N + 1, ", R + 2, "]");
  AT_DISPATCH_FLOATING_TYPES(table.scalar_type(), "composite_backward", [&] {
    backward_impl<scalar_t>(table.contiguous(), gid.contiguous(), offset.contiguous(), active.contiguous(),
                            centers.contiguous(), t_entry.contiguous(), n_incl.contiguous(), g_out.contiguous(),
                            total.contiguous(), prefix, grads, int(tile));
  });
}
