// The native CPU kernels and their Python bindings (render/_native.py builds and loads them).
// One translation unit: torch's headers are compiled once, which halves the first build.
#include "binning.cpp"
#include "composite.cpp"
#include "project.cpp"
#include "loss.cpp"

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("composite_forward", &composite_forward, "one depth chunk's compositing, forward");
  m.def("composite_backward", &composite_backward, "one depth chunk's compositing, backward");
  m.def("project_forward", &project_forward, "projection and SH colour of every Gaussian, forward");
  m.def("project_backward", &project_backward, "projection and SH colour of every Gaussian, backward");
  m.def("photometric_forward", &photometric_forward, "(1 - lambda) L1 + lambda (1 - SSIM) of one image, forward");
  m.def("photometric_backward", &photometric_backward, "(1 - lambda) L1 + lambda (1 - SSIM) of one image, backward");
  m.def("stable_order", &stable_order, "the stable ascending order of 1-D float keys (a radix sort)");
  m.def("footprints", &footprints, "the visible Gaussians front to back and their tile rectangles");
  m.def("bin_chunk", &bin_chunk, "the next depth chunk's (tile, Gaussian) pairs, sorted by (tile, depth)");
}
