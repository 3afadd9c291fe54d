"""The example plugin's model and densification strategy.

The model is the framework's GaussianModel with one extra loss term; its
strategy shows the densification seam: a ``Strategy`` subclass that sees only
the parameter and optimizer dicts, built by its config kind (``PruneOnlyConfig``).
"""

import torch

from splat_framework.plugin import GaussianModel, Strategy, ops


class PruneOnlyStrategy(Strategy):
    """Never grows the model: every ``every`` iterations removes the Gaussians whose opacity is below
    ``min_opacity`` (the toy counterpart of gsplat's strategies, on the same interface)."""

    def __init__(self, config) -> None:
        super().__init__(config)  # self.config
        self.min_opacity = float(config.min_opacity)
        self.every = int(config.every)

    def check_sanity(self, params, optimizers):
        if "opacities" not in params:
            raise ValueError("PruneOnlyStrategy needs params['opacities']")

    def step_post_backward(self, params, optimizers, state, step, info):
        if step == 0 or step % self.every:
            return {}
        drop = torch.sigmoid(params["opacities"].detach().flatten()) < self.min_opacity
        n = int(drop.sum())
        if 0 < n < drop.numel():  # never empty the model
            ops.remove(params, optimizers, state, drop)
        return {"n_prune": n}


class FlatGaussianModel(GaussianModel):
    """3DGS whose Gaussians are gently pushed towards isotropy (a toy regulariser)."""

    def get_loss_dict(self, outputs, batch, camera, step):
        losses = super().get_loss_dict(outputs, batch, camera, step)
        s = self.params["scales"]
        losses["isotropy"] = 0.01 * (s - s.mean(dim=1, keepdim=True)).abs().mean()
        return losses
