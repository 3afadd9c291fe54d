// The native CPU kernels' entry points (bound to Python in module.cpp).
#pragma once
#include <torch/extension.h>

#include <tuple>

// composite.cpp: one depth chunk's compositing. Forward: (t_state, out updated in place) ->
// n_incl [A, P] int32. Backward: (prefix [T, P] and grads [slots, N + 1, R] updated in place).
torch::Tensor composite_forward(torch::Tensor table, torch::Tensor gid, torch::Tensor offset, torch::Tensor count,
                                torch::Tensor active, torch::Tensor centers, torch::Tensor t_state,
                                torch::Tensor out, int64_t tile);
void composite_backward(torch::Tensor table, torch::Tensor gid, torch::Tensor offset, torch::Tensor active,
                        torch::Tensor centers, torch::Tensor t_entry, torch::Tensor n_incl, torch::Tensor g_out,
                        torch::Tensor total, torch::Tensor prefix, torch::Tensor grads, int64_t tile);

// binning.cpp: the next depth chunk's (tile, Gaussian) pairs ->
// (gid_sorted [Pc], tile_count [T], tile_offset [T], position after the chunk).
std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, int64_t> bin_chunk(
    torch::Tensor ids, torch::Tensor tx0, torch::Tensor tx1, torch::Tensor ty0, torch::Tensor ty1, torch::Tensor ell,
    torch::Tensor tile_done, int64_t pos, int64_t chunk_pairs, int64_t tile, int64_t ntx, int64_t nty, int64_t width,
    int64_t height);
