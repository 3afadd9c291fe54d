"""The example plugin's model: the framework's GaussianModel with one extra loss term."""

import torch

from splat_framework.model.gaussians import GaussianModel


class FlatGaussianModel(GaussianModel):
    """3DGS whose Gaussians are gently pushed towards isotropy (a toy regulariser)."""

    def get_loss_dict(self, outputs, batch, camera, step):
        losses = super().get_loss_dict(outputs, batch, camera, step)
        s = self.params["scales"]
        losses["isotropy"] = 0.01 * (s - s.mean(dim=1, keepdim=True)).abs().mean()
        return losses
