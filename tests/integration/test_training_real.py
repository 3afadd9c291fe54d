"""Short training runs on the real fern scene (../shared/data, or $SPLAT_DATA).

Skipped with a reason when the data is absent. Runs at 252x189 (downscale 16)
for a few hundred iterations so CI stays fast; the full-resolution figures are
produced by benchmarks/full_run.py and benchmarks/ablation.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from splat_framework.engine.trainer import Trainer
from splat_framework.evaluation.held_out import evaluate
from splat_framework.registry import get_method
from support import DATA

FERN = DATA / "llff" / "fern"

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(not FERN.is_dir(), reason=f"real dataset llff/fern not found under {DATA} (set SPLAT_DATA)"),
]


def _trainer(method: str, tmp_path: Path, steps: int) -> Trainer:
    cfg = get_method(method).default_config().model_copy(
        update=dict(data=str(FERN), views=3, downscale=16, steps=steps, output=tmp_path / method, progress=False, save_renders=False)
    )
    return Trainer(cfg)


@pytest.mark.parametrize("method", ["3dgs", "scgaussian"])
def test_short_training_on_fern_beats_the_untrained_model(method, tmp_path, monkeypatch):
    # the kernels a training run on a CPU uses: native compositing, projection and loss (eager
    # torch ones took 3-4x as long here: 541 s for scgaussian on the 2-core machine)
    monkeypatch.setenv("SPLAT_COMPILE", "1")
    tr = _trainer(method, tmp_path, steps=300)
    assert tr.datamanager.scene.train_indices == [1, 10, 19]
    before = evaluate(tr.model, tr.datamanager, tr.background)["mean"]["psnr"]
    metrics = tr.train()
    after = metrics["mean"]["psnr"]
    assert after > before + 3.0, (before, after)
    saved = json.loads((tmp_path / method / "metrics.json").read_text())
    assert saved["mean"]["psnr"] == pytest.approx(after)
    assert [v["index"] for v in saved["per_view"]] == [0, 8, 16]
    if method == "scgaussian":
        assert saved["init_stats"]["num_matches"] > 1000
        # the matches it trained on, by name: the cached set the prior reads gives the same digest
        from splat_framework.plugin import compute_match_set
        digest = compute_match_set(tr.config.model.matching, tr.datamanager).digest()
        assert saved["init_stats"]["matches_digest"] == digest
        assert {"matching_s", "warmup_s", "train_s", "eval_s", "total_s"} <= set(saved["timing"])
