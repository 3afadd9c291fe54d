"""The method's model and strategy, imported when training starts (they import torch)."""

import torch

from splat_framework.plugin import GaussianModel, Strategy, ops


class MyModel(GaussianModel):
    def get_loss_dict(self, outputs, batch, camera, step):
        losses = super().get_loss_dict(outputs, batch, camera, step)
        s = self.params["scales"]  # [N, 3], stored as log-scales
        losses["isotropy"] = 0.01 * (s - s.mean(dim=1, keepdim=True)).abs().mean()
        return losses


class MyPruneStrategy(Strategy):
    def step_post_backward(self, params, optimizers, state, step, info):
        drop = torch.sigmoid(params["opacities"].detach()) < self.config.min_opacity  # stored as logits
        n = int(drop.sum())
        if not 0 < n < len(drop):  # none to remove, or all: the model is never emptied
            return {}
        ops.remove(params, optimizers, state, drop)
        return {"n_prune": n}
