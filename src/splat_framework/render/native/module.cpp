// The native CPU kernels and their Python bindings (render/_native.py builds and loads them).
// One translation unit: torch's headers are compiled once, which halves the first build.
#include "binning.cpp"
#include "composite.cpp"

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("composite_forward", &composite_forward, "one depth chunk's compositing, forward");
  m.def("composite_backward", &composite_backward, "one depth chunk's compositing, backward");
  m.def("bin_chunk", &bin_chunk, "the next depth chunk's (tile, Gaussian) pairs, sorted by (tile, depth)");
}
