// Native CPU binning of one depth chunk: the same rules as _composite.py's torch binning
// (_iter_chunks, _chunk_pairs, _row_columns), in one pass and a counting sort instead of a
// few dozen small tensor ops.
//
// Shapes (V visible Gaussians, front to back; T = ntx * nty tiles):
//   ids        [V]     Gaussian indices, sorted by depth
//   tx0 .. ty1 [V]     their tile rectangles (inclusive)
//   ell        [V, 6]  (u, v, cov_xx, cov_xy, cov_yy, qmax): the ellipse where alpha >= 1/255
//   tile_done  [T]     bool, every pixel of the tile has stopped
#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

namespace {

// Tile columns [c0, c1] that the ellipse d^T cov^-1 d <= qmax reaches within tile row `row`
// (conservative: the whole band between the row's first and last pixel-centre lines);
// c1 < c0 when it reaches none. The same arithmetic as _row_columns.
template <typename S>
void row_columns(const S* e, int64_t row, int64_t tile, int64_t width, int64_t height, int64_t& c0, int64_t& c1) {
  const S u = e[0], v = e[1], sxy = e[3], q = e[5];
  const S sxx = std::max(e[2], S(1e-12)), syy = std::max(e[4], S(1e-12));
  const S top = S(row) * S(tile);
  const S ey = std::sqrt(q * syy);
  const S dyl = std::max(top + S(0.5) - v, -ey);
  S dyh = std::min(std::min(top + (S(tile) - S(0.5)), S(height) - S(0.5)) - v, ey);
  const bool empty = dyl > dyh;
  dyh = std::max(dyh, dyl);
  const S k = sxy / syy;
  const S w2 = std::max(sxx - sxy * k, S(0)) / syy;
  const S d_star = sxy * std::sqrt(q / sxx);  // dy of the rightmost point (leftmost: -d_star)
  const auto half = [&](S dy) { return std::sqrt(std::max(q * syy - dy * dy, S(0)) * w2); };
  const S dr = std::min(std::max(d_star, dyl), dyh);
  const S dl = std::min(std::max(-d_star, dyl), dyh);
  const S x_hi = u + k * dr + half(dr);
  const S x_lo = u + k * dl - half(dl);
  const S margin = S(1e-3) + S(1e-5) * (std::abs(x_hi) + std::abs(x_lo));
  const S big = S(width + tile);
  const S p_lo = std::ceil(std::clamp(x_lo - S(0.5) - margin, -big, big));
  const S p_hi = std::floor(std::clamp(x_hi - S(0.5) + margin, -big, big));
  if (!(p_lo == p_lo) || !(p_hi == p_hi)) {  // NaN: reaches nothing
    c0 = 0;
    c1 = -1;
    return;
  }
  c0 = int64_t(std::clamp(p_lo, S(0), S(width - 1))) / tile;
  c1 = int64_t(std::clamp(p_hi, S(0), S(width - 1))) / tile;
  if (empty || p_hi < 0 || p_lo > S(width - 1) || p_lo > p_hi) c1 = c0 - 1;
}

template <typename S>
std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, int64_t> bin_impl(
    const torch::Tensor& ids, const torch::Tensor& tx0, const torch::Tensor& tx1, const torch::Tensor& ty0,
    const torch::Tensor& ty1, const torch::Tensor& ell, const torch::Tensor& tile_done, int64_t pos,
    int64_t chunk_pairs, int64_t tile, int64_t ntx, int64_t nty, int64_t width, int64_t height) {
  const int64_t n_tiles = ntx * nty, n_vis = ids.size(0);
  const int64_t* id = ids.data_ptr<int64_t>();
  const int64_t *x0 = tx0.data_ptr<int64_t>(), *x1 = tx1.data_ptr<int64_t>();
  const int64_t *y0 = ty0.data_ptr<int64_t>(), *y1 = ty1.data_ptr<int64_t>();
  const S* el = ell.data_ptr<S>();
  const bool* done = tile_done.data_ptr<bool>();

  // summed-area table of the unfinished tiles: each rectangle's count in four reads
  const int64_t w1 = ntx + 1;
  std::vector<int64_t> sat((nty + 1) * w1, 0);
  for (int64_t y = 0; y < nty; ++y)
    for (int64_t x = 0; x < ntx; ++x)
      sat[(y + 1) * w1 + x + 1] = int64_t(!done[y * ntx + x]) + sat[y * w1 + x + 1] + sat[(y + 1) * w1 + x] - sat[y * w1 + x];
  const auto alive_in = [&](int64_t j) {
    const int64_t a = y0[j] * w1, b = (y1[j] + 1) * w1, l = x0[j], r = x1[j] + 1;
    return sat[b + r] - sat[a + r] - sat[b + l] + sat[a + l];
  };

  // the chunk: the longest run from pos whose rectangles hold at most chunk_pairs unfinished
  // tiles in all (at least one Gaussian)
  int64_t end = pos, cum = 0;
  while (end < n_vis) {
    const int64_t c = alive_in(end);
    if (end > pos && cum + c > chunk_pairs) break;
    cum += c;
    ++end;
  }

  // pairs (unfinished tile, Gaussian) in depth order, per (Gaussian, tile row) over the columns the
  // ellipse reaches, on torch's intra-op threads: slice s of the chunk's Gaussians lists its pairs
  // and counts them per tile; a stable counting sort by tile then keeps the depth order within each
  // tile (slice s's pairs of a tile come after those of slices < s).
  const int64_t slices = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), cum / 16384 + 1));
  // The lists live from call to call in the calling thread (a step bins a few chunks of about
  // the same size): fresh pages for them on every call were faulted in one thread at a time, and
  // two threads binned no faster than one. Named here, as references: inside the parallel region
  // a thread_local's own name is each worker's copy.
  thread_local std::vector<std::vector<int32_t>> kept_tile, kept_pos;
  thread_local std::vector<std::vector<int64_t>> kept_cnt;
  std::vector<std::vector<int32_t>>& pair_tile = kept_tile;  // [slices][pairs] tile
  std::vector<std::vector<int32_t>>& pair_pos = kept_pos;    // [slices][pairs] position in ids
  std::vector<std::vector<int64_t>>& slice_cnt = kept_cnt;   // [slices][T] pairs per tile
  if (int64_t(pair_tile.size()) < slices) {
    pair_tile.resize(slices);
    pair_pos.resize(slices);
    slice_cnt.resize(slices);
  }
  const int64_t len = end - pos;
  at::parallel_for(0, slices, 1, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      std::vector<int32_t>& tiles = pair_tile[s];
      std::vector<int32_t>& where = pair_pos[s];
      tiles.clear();
      where.clear();
      tiles.reserve(cum / slices + 1024);
      where.reserve(cum / slices + 1024);
      slice_cnt[s].assign(n_tiles, 0);
      int64_t* cnt = slice_cnt[s].data();
      for (int64_t j = pos + len * s / slices; j < pos + len * (s + 1) / slices; ++j) {
        if (alive_in(j) == 0) continue;
        for (int64_t row = y0[j]; row <= y1[j]; ++row) {
          int64_t c0, c1;
          row_columns(el + j * 6, row, tile, width, height, c0, c1);
          c0 = std::max(c0, x0[j]);
          c1 = std::min(c1, x1[j]);
          for (int64_t c = c0; c <= c1; ++c) {
            const int64_t t = row * ntx + c;
            if (done[t]) continue;
            tiles.push_back(int32_t(t));
            where.push_back(int32_t(j));
            ++cnt[t];
          }
        }
      }
    }
  });
  auto count = torch::zeros({n_tiles}, ids.options());
  auto offset = torch::empty({n_tiles}, ids.options());
  int64_t* cnt = count.data_ptr<int64_t>();
  int64_t* off = offset.data_ptr<int64_t>();
  int64_t run = 0;
  for (int64_t t = 0; t < n_tiles; ++t) {
    off[t] = run;
    for (int64_t s = 0; s < slices; ++s) {
      const int64_t c = slice_cnt[s][t];
      slice_cnt[s][t] = run;  // now: where slice s's pairs of tile t begin
      run += c;
    }
    cnt[t] = run - off[t];
  }
  auto gid = torch::empty({run}, ids.options());
  int64_t* g = gid.data_ptr<int64_t>();
  at::parallel_for(0, slices, 1, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      int64_t* cursor = slice_cnt[s].data();
      const std::vector<int32_t>& tiles = pair_tile[s];
      const std::vector<int32_t>& where = pair_pos[s];
      for (size_t p = 0; p < tiles.size(); ++p) g[cursor[tiles[p]]++] = id[where[p]];
    }
  });
  return {gid, count, offset, end};
}

// Stable LSD radix sort of V finite keys, 11 bits a pass: the permutation [V] that
// torch.argsort(keys, stable=True) gives (a float's bits, the sign flipped and, for negatives,
// every bit, order as the floats do; -0 is taken as +0). Passes whose digit is the same for every
// key (depths share their top bits) are skipped. About 10x faster than torch's stable argsort for
// 100k depths on CPU, one thread.
template <typename S, typename U>
torch::Tensor order_impl(const torch::Tensor& keys) {
  constexpr int BITS = 11, BUCKETS = 1 << BITS, WIDTH = int(sizeof(U)) * 8;
  constexpr int PASSES = (WIDTH + BITS - 1) / BITS;
  const int64_t n = keys.size(0);
  const S* k = keys.data_ptr<S>();
  auto order = torch::empty({n}, keys.options().dtype(torch::kInt64));
  std::vector<U> key_a(n), key_b(n);
  std::vector<int64_t> idx_b(n);
  std::vector<int64_t> hist(int64_t(PASSES) * BUCKETS, 0);
  int64_t* idx_a = order.data_ptr<int64_t>();
  for (int64_t i = 0; i < n; ++i) {
    const S x = k[i] + S(0);  // -0 -> +0
    U b;
    std::memcpy(&b, &x, sizeof(U));
    b ^= (b >> (WIDTH - 1)) ? ~U(0) : (U(1) << (WIDTH - 1));
    key_a[i] = b;
    idx_a[i] = i;
    for (int p = 0; p < PASSES; ++p) ++hist[p * BUCKETS + int((b >> (p * BITS)) & (BUCKETS - 1))];
  }
  U* src_key = key_a.data();
  U* dst_key = key_b.data();
  int64_t* src_idx = idx_a;
  int64_t* dst_idx = idx_b.data();
  for (int p = 0; p < PASSES; ++p) {
    int64_t* h = hist.data() + p * BUCKETS;
    if (n == 0 || *std::max_element(h, h + BUCKETS) == n) continue;  // one digit for all: order kept
    int64_t run = 0;
    for (int d = 0; d < BUCKETS; ++d) {
      const int64_t c = h[d];
      h[d] = run;
      run += c;
    }
    for (int64_t i = 0; i < n; ++i) {
      const int64_t at = h[int((src_key[i] >> (p * BITS)) & (BUCKETS - 1))]++;
      dst_key[at] = src_key[i];
      dst_idx[at] = src_idx[i];
    }
    std::swap(src_key, dst_key);
    std::swap(src_idx, dst_idx);
  }
  if (src_idx != idx_a) std::copy(src_idx, src_idx + n, idx_a);
  return order;
}

// The visible Gaussians front to back and their tile rectangles, the arithmetic of
// _composite.tile_footprints in the same precision: pixel index ranges whose centres may be
// inside (u +- ext_x - 0.5 rounded inwards), the Gaussians whose range meets the image, their
// stable depth order (order_impl) and the rows gathered in that order.
template <typename S, typename U>
std::vector<torch::Tensor> footprints_impl(const torch::Tensor& means2d, const torch::Tensor& ext_x,
                                           const torch::Tensor& ext_y, const torch::Tensor& ok,
                                           const torch::Tensor& depths, const torch::Tensor& cov2d,
                                           const torch::Tensor& qmax, int64_t width, int64_t height, int64_t tile) {
  const int64_t n = means2d.size(0);
  const S* m = means2d.data_ptr<S>();
  const S *ex = ext_x.data_ptr<S>(), *ey = ext_y.data_ptr<S>(), *d = depths.data_ptr<S>();
  const S *cv = cov2d.data_ptr<S>(), *q = qmax.data_ptr<S>();
  const bool* good = ok.data_ptr<bool>();
  auto hit = torch::empty({n}, ok.options());
  bool* h = hit.data_ptr<bool>();
  std::vector<S> rect(size_t(n) * 4);  // px0, px1, py0, py1
  std::vector<int64_t> visible;
  visible.reserve(n);
  const S half = S(0.5), right = S(width - 1), bottom = S(height - 1);
  for (int64_t i = 0; i < n; ++i) {
    const S u = m[2 * i], v = m[2 * i + 1];
    const S px0 = std::ceil(u - ex[i] - half), px1 = std::floor(u + ex[i] - half);
    const S py0 = std::ceil(v - ey[i] - half), py1 = std::floor(v + ey[i] - half);
    S* r = rect.data() + 4 * i;
    r[0] = px0;
    r[1] = px1;
    r[2] = py0;
    r[3] = py1;
    h[i] = good[i] && px1 >= S(0) && px0 <= right && py1 >= S(0) && py0 <= bottom && px0 <= px1 && py0 <= py1;
    if (h[i]) visible.push_back(i);
  }
  const int64_t nv = int64_t(visible.size());
  auto long_opts = means2d.options().dtype(torch::kInt64);
  auto keys = torch::empty({nv}, depths.options());
  S* k = keys.data_ptr<S>();
  for (int64_t j = 0; j < nv; ++j) k[j] = d[visible[j]];
  const torch::Tensor order = order_impl<S, U>(keys);
  const int64_t* o = order.data_ptr<int64_t>();
  auto ids = torch::empty({nv}, long_opts);
  auto tx0 = torch::empty({nv}, long_opts), tx1 = torch::empty({nv}, long_opts);
  auto ty0 = torch::empty({nv}, long_opts), ty1 = torch::empty({nv}, long_opts);
  auto ell = torch::empty({nv, 6}, means2d.options());
  int64_t *id = ids.data_ptr<int64_t>(), *x0 = tx0.data_ptr<int64_t>(), *x1 = tx1.data_ptr<int64_t>();
  int64_t *y0 = ty0.data_ptr<int64_t>(), *y1 = ty1.data_ptr<int64_t>();
  S* e = ell.data_ptr<S>();
  const auto tile_of = [&](S p, S hi) { return int64_t(std::min(std::max(p, S(0)), hi)) / tile; };
  for (int64_t j = 0; j < nv; ++j) {
    const int64_t i = visible[o[j]];
    const S* r = rect.data() + 4 * i;
    id[j] = i;
    x0[j] = tile_of(r[0], right);
    x1[j] = tile_of(r[1], right);
    y0[j] = tile_of(r[2], bottom);
    y1[j] = tile_of(r[3], bottom);
    S* row = e + 6 * j;
    row[0] = m[2 * i];
    row[1] = m[2 * i + 1];
    row[2] = cv[3 * i];
    row[3] = cv[3 * i + 1];
    row[4] = cv[3 * i + 2];
    row[5] = q[i];
  }
  return {ids, tx0, tx1, ty0, ty1, ell, hit};
}

}  // namespace

// keys [V] (finite) -> [V] int64, the stable ascending order (torch.argsort(keys, stable=True))
torch::Tensor stable_order(torch::Tensor keys) {
  TORCH_CHECK(keys.device().is_cpu() && keys.dim() == 1, "stable_order sorts a 1-D CPU tensor");
  if (keys.scalar_type() == torch::kFloat) return order_impl<float, uint32_t>(keys.contiguous());
  TORCH_CHECK(keys.scalar_type() == torch::kDouble, "stable_order sorts float32 or float64 keys");
  return order_impl<double, uint64_t>(keys.contiguous());
}

std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, int64_t> bin_chunk(
    torch::Tensor ids, torch::Tensor tx0, torch::Tensor tx1, torch::Tensor ty0, torch::Tensor ty1, torch::Tensor ell,
    torch::Tensor tile_done, int64_t pos, int64_t chunk_pairs, int64_t tile, int64_t ntx, int64_t nty, int64_t width,
    int64_t height) {
  TORCH_CHECK(ids.device().is_cpu() && ell.device().is_cpu(), "native binning runs on CPU tensors");
  TORCH_CHECK(ids.scalar_type() == torch::kInt64 && tx0.scalar_type() == torch::kInt64, "ids and rectangles must be int64");
  TORCH_CHECK(tile_done.scalar_type() == torch::kBool && tile_done.numel() == ntx * nty, "tile_done must be [ntx * nty] bool");
  TORCH_CHECK(ell.dim() == 2 && ell.size(1) == 6 && ell.size(0) == ids.size(0), "ell must be [V, 6]");
  TORCH_CHECK(tile > 0 && pos >= 0 && pos <= ids.size(0), "bad tile size or position");
  TORCH_CHECK(ids.size(0) < (int64_t(1) << 31) && ntx * nty < (int64_t(1) << 31),
              "binning lists positions and tiles as 32-bit integers");
  std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, int64_t> result;
  AT_DISPATCH_FLOATING_TYPES(ell.scalar_type(), "bin_chunk", [&] {
    result = bin_impl<scalar_t>(ids.contiguous(), tx0.contiguous(), tx1.contiguous(), ty0.contiguous(),
                                ty1.contiguous(), ell.contiguous(), tile_done.contiguous(), pos, chunk_pairs, tile,
                                ntx, nty, width, height);
  });
  return result;
}

// (means2d [N, 2], ext_x, ext_y [N], ok [N] bool, depths [N], cov2d [N, 3], qmax [N]) ->
// [ids, tx0, tx1, ty0, ty1 [V] int64, ell [V, 6], hit [N] bool]: _composite.tile_footprints
std::vector<torch::Tensor> footprints(torch::Tensor means2d, torch::Tensor ext_x, torch::Tensor ext_y, torch::Tensor ok,
                                      torch::Tensor depths, torch::Tensor cov2d, torch::Tensor qmax, int64_t width,
                                      int64_t height, int64_t tile) {
  const int64_t n = means2d.size(0);
  TORCH_CHECK(means2d.device().is_cpu() && means2d.dim() == 2 && means2d.size(1) == 2, "means2d must be [N, 2] on the CPU");
  TORCH_CHECK(cov2d.dim() == 2 && cov2d.size(0) == n && cov2d.size(1) == 3, "cov2d must be [N, 3]");
  TORCH_CHECK(ext_x.numel() == n && ext_y.numel() == n && depths.numel() == n && qmax.numel() == n && ok.numel() == n,
              "one extent, depth, qmax and flag per Gaussian");
  TORCH_CHECK(ok.scalar_type() == torch::kBool && tile > 0, "ok must be bool, tile positive");
  const auto st = means2d.scalar_type();
  for (const auto* t : {&ext_x, &ext_y, &depths, &cov2d, &qmax})
    TORCH_CHECK(t->scalar_type() == st, "footprints: every float input in the dtype of means2d");
  if (st == torch::kFloat)
    return footprints_impl<float, uint32_t>(means2d.contiguous(), ext_x.contiguous(), ext_y.contiguous(), ok.contiguous(),
                                            depths.contiguous(), cov2d.contiguous(), qmax.contiguous(), width, height, tile);
  TORCH_CHECK(st == torch::kDouble, "footprints: float32 or float64");
  return footprints_impl<double, uint64_t>(means2d.contiguous(), ext_x.contiguous(), ext_y.contiguous(), ok.contiguous(),
                                           depths.contiguous(), cov2d.contiguous(), qmax.contiguous(), width, height, tile);
}
