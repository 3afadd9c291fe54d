// Native CPU photometric loss of one image: (1 - lambda) L1 + lambda (1 - SSIM), forward and
// hand-derived backward with respect to the prediction.
//
// The same SSIM as losses.ssim_map (the 3DGS reference's): the five local statistics (x, y, x^2,
// y^2, xy) blurred by a separable Gaussian window with zero padding, C1 = 0.01^2, C2 = 0.03^2, the
// mean over every pixel and channel. The backward blurs the three statistics' gradients with the
// same window (a symmetric window with zero padding is its own transpose). Every sum runs in a
// fixed order (rows in parallel, each row's sum kept, then the rows added in order), so the loss
// and its gradient do not depend on the thread count; nothing is traced or compiled at run time.
//
// Shapes: pred, gt [H, W, C]; taps [window] (the normalised 1D Gaussian); stats [H, W, 5, C] (the
// blurred statistics the forward returns for the backward).
#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <cmath>
#include <tuple>
#include <vector>

namespace {

constexpr double SSIM_C1 = 0.01 * 0.01;
constexpr double SSIM_C2 = 0.03 * 0.03;

// out = V(H(in)) for in, out [h, w, n] (n values per pixel), zero padding; tmp [h, w, n].
template <typename T>
void blur(const T* in, T* out, T* tmp, int64_t h, int64_t w, int64_t n, const T* taps, int64_t win) {
  const int64_t r = win / 2;
  at::parallel_for(0, h, 8, [&](int64_t begin, int64_t end) {
    for (int64_t y = begin; y < end; ++y) {
      T* o = tmp + y * w * n;
      const T* s = in + y * w * n;
      for (int64_t i = 0; i < w * n; ++i) o[i] = T(0);
      for (int64_t k = 0; k < win; ++k) {  // tap k over the pixels it reaches: one contiguous run
        const int64_t x0 = std::max<int64_t>(0, r - k), x1 = std::min<int64_t>(w, w + r - k);
        const int64_t shift = (k - r) * n;
        const T g = taps[k];
        for (int64_t i = x0 * n; i < x1 * n; ++i) o[i] += g * s[i + shift];
      }
    }
  });
  at::parallel_for(0, h, 8, [&](int64_t begin, int64_t end) {
    for (int64_t y = begin; y < end; ++y) {
      T* o = out + y * w * n;
      for (int64_t i = 0; i < w * n; ++i) o[i] = T(0);
      const int64_t k0 = std::max<int64_t>(0, r - y), k1 = std::min<int64_t>(win, h + r - y);
      for (int64_t k = k0; k < k1; ++k) {
        const T* s = tmp + (y + k - r) * w * n;
        const T g = taps[k];
        for (int64_t i = 0; i < w * n; ++i) o[i] += g * s[i];
      }
    }
  });
}

void check(const torch::Tensor& pred, const torch::Tensor& gt, const torch::Tensor& taps) {
  TORCH_CHECK(pred.dim() == 3 && pred.sizes() == gt.sizes(), "pred and gt must be one [H, W, C] shape");
  TORCH_CHECK(pred.device().is_cpu() && gt.device().is_cpu(), "the native loss runs on the CPU");
  TORCH_CHECK(gt.scalar_type() == pred.scalar_type() && taps.scalar_type() == pred.scalar_type(),
              "pred, gt and taps must share one dtype");
  TORCH_CHECK(taps.dim() == 1 && taps.size(0) % 2 == 1, "taps must be an odd-length 1D window");
}

}  // namespace

// (loss [], stats [H, W, 5, C])
std::tuple<torch::Tensor, torch::Tensor> photometric_forward(torch::Tensor pred, torch::Tensor gt, torch::Tensor taps,
                                                             double lambda_dssim) {
  check(pred, gt, taps);
  pred = pred.contiguous();
  gt = gt.contiguous();
  taps = taps.contiguous();
  const int64_t h = pred.size(0), w = pred.size(1), c = pred.size(2);
  auto stack = torch::empty({h, w, 5, c}, pred.options());
  auto stats = torch::empty({h, w, 5, c}, pred.options());
  auto tmp = torch::empty({h, w, 5, c}, pred.options());
  auto rows = torch::empty({h, 2}, pred.options().dtype(torch::kDouble));
  torch::Tensor loss;
  AT_DISPATCH_FLOATING_TYPES(pred.scalar_type(), "photometric_forward", [&] {
    const scalar_t* x = pred.data_ptr<scalar_t>();
    const scalar_t* y = gt.data_ptr<scalar_t>();
    scalar_t* st = stack.data_ptr<scalar_t>();
    at::parallel_for(0, h * w, 1024, [&](int64_t begin, int64_t end) {
      for (int64_t p = begin; p < end; ++p)
        for (int64_t k = 0; k < c; ++k) {
          const scalar_t a = x[p * c + k], b = y[p * c + k];
          scalar_t* s = st + p * 5 * c;
          s[k] = a;
          s[c + k] = b;
          s[2 * c + k] = a * a;
          s[3 * c + k] = b * b;
          s[4 * c + k] = a * b;
        }
    });
    scalar_t* S = stats.data_ptr<scalar_t>();
    blur<scalar_t>(st, S, tmp.data_ptr<scalar_t>(), h, w, 5 * c, taps.data_ptr<scalar_t>(), taps.size(0));
    double* rs = rows.data_ptr<double>();
    const scalar_t c1 = scalar_t(SSIM_C1), c2 = scalar_t(SSIM_C2);
    at::parallel_for(0, h, 8, [&](int64_t begin, int64_t end) {
      for (int64_t yy = begin; yy < end; ++yy) {
        double l1 = 0.0, ss = 0.0;
        for (int64_t xx = 0; xx < w; ++xx) {
          const int64_t p = yy * w + xx;
          const scalar_t* s = S + p * 5 * c;
          for (int64_t k = 0; k < c; ++k) {
            const scalar_t mu1 = s[k], mu2 = s[c + k];
            const scalar_t s1 = s[2 * c + k] - mu1 * mu1, s2 = s[3 * c + k] - mu2 * mu2, s12 = s[4 * c + k] - mu1 * mu2;
            const scalar_t m = ((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1 * mu1 + mu2 * mu2 + c1) * (s1 + s2 + c2));
            ss += double(m);
            l1 += double(std::abs(x[p * c + k] - y[p * c + k]));
          }
        }
        rs[2 * yy] = l1;
        rs[2 * yy + 1] = ss;
      }
    });
    double l1 = 0.0, ss = 0.0;
    for (int64_t yy = 0; yy < h; ++yy) {
      l1 += rs[2 * yy];
      ss += rs[2 * yy + 1];
    }
    const double count = double(h * w * c);
    loss = torch::full({}, (1.0 - lambda_dssim) * l1 / count + lambda_dssim * (1.0 - ss / count), pred.options());
  });
  return {loss, stats};
}

// d loss / d pred, times grad (a scalar tensor)
torch::Tensor photometric_backward(torch::Tensor pred, torch::Tensor gt, torch::Tensor taps, double lambda_dssim,
                                   torch::Tensor stats, torch::Tensor grad) {
  check(pred, gt, taps);
  pred = pred.contiguous();
  gt = gt.contiguous();
  taps = taps.contiguous();
  stats = stats.contiguous();
  const int64_t h = pred.size(0), w = pred.size(1), c = pred.size(2);
  TORCH_CHECK(stats.numel() == h * w * 5 * c, "stats do not match the image");
  auto gstats = torch::empty({h, w, 3, c}, pred.options());
  auto blurred = torch::empty({h, w, 3, c}, pred.options());
  auto tmp = torch::empty({h, w, 3, c}, pred.options());
  auto out = torch::empty_like(pred);
  const double g = grad.item<double>();
  const double count = double(h * w * c);
  AT_DISPATCH_FLOATING_TYPES(pred.scalar_type(), "photometric_backward", [&] {
    const scalar_t* x = pred.data_ptr<scalar_t>();
    const scalar_t* y = gt.data_ptr<scalar_t>();
    const scalar_t* S = stats.data_ptr<scalar_t>();
    scalar_t* G = gstats.data_ptr<scalar_t>();
    const scalar_t c1 = scalar_t(SSIM_C1), c2 = scalar_t(SSIM_C2);
    const scalar_t gm = scalar_t(-lambda_dssim * g / count);  // d loss / d ssim_map(p, k)
    at::parallel_for(0, h * w, 1024, [&](int64_t begin, int64_t end) {
      for (int64_t p = begin; p < end; ++p) {
        const scalar_t* s = S + p * 5 * c;
        scalar_t* o = G + p * 3 * c;
        for (int64_t k = 0; k < c; ++k) {
          const scalar_t mu1 = s[k], mu2 = s[c + k];
          const scalar_t s1 = s[2 * c + k] - mu1 * mu1, s2 = s[3 * c + k] - mu2 * mu2, s12 = s[4 * c + k] - mu1 * mu2;
          const scalar_t A = 2 * mu1 * mu2 + c1, B = 2 * s12 + c2;
          const scalar_t Cc = mu1 * mu1 + mu2 * mu2 + c1, D = s1 + s2 + c2;
          const scalar_t m = (A * B) / (Cc * D);
          // d m / d mu1, d ex2, d exy (mu1 enters A, B (s12), Cc and D (s1))
          o[k] = gm * ((2 * mu2 * B - 2 * mu2 * A) / (Cc * D) - m * (2 * mu1 / Cc - 2 * mu1 / D));
          o[c + k] = gm * (-m / D);
          o[2 * c + k] = gm * (2 * A / (Cc * D));
        }
      }
    });
    scalar_t* Bl = blurred.data_ptr<scalar_t>();
    blur<scalar_t>(G, Bl, tmp.data_ptr<scalar_t>(), h, w, 3 * c, taps.data_ptr<scalar_t>(), taps.size(0));
    scalar_t* dx = out.data_ptr<scalar_t>();
    const scalar_t gl1 = scalar_t((1.0 - lambda_dssim) * g / count);
    at::parallel_for(0, h * w, 1024, [&](int64_t begin, int64_t end) {
      for (int64_t p = begin; p < end; ++p) {
        const scalar_t* b = Bl + p * 3 * c;
        for (int64_t k = 0; k < c; ++k) {
          const scalar_t a = x[p * c + k], t = y[p * c + k];
          const scalar_t d = a - t;
          const scalar_t sgn = d > 0 ? scalar_t(1) : (d < 0 ? scalar_t(-1) : scalar_t(0));
          dx[p * c + k] = b[k] + 2 * a * b[c + k] + t * b[2 * c + k] + gl1 * sgn;
        }
      }
    });
  });
  return out;
}
