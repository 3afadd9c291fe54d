"""A pipeline that feeds the model two training views a step (the seam of a binocular or multi-view
consistency loss): the step's view, scored as the model scores it, and its neighbour in the
training order, rendered too and scored by the photometric loss, ``two_view_weight`` times."""

from splat_framework.plugin import Pipeline, photometric_loss, section


class TwoViewPipeline(Pipeline):
    """The framework's pipeline plus a second view's render and loss term (``second_view``)."""

    def train_losses(self, step):
        outputs, batch, losses = super().train_losses(step)
        second = (int(batch["train_position"]) + 1) % self.datamanager.num_train
        camera, other = self.datamanager.train_view(second)
        with section("second view"):
            render = self.model.get_outputs(camera, self.background, step=step)
            weight = self.config.model.two_view_weight
            losses["second_view"] = weight * photometric_loss(render.rgb, other["image"], self.config.model.lambda_dssim,
                                                                settings=self.model.render_settings)
        return outputs, batch, losses
