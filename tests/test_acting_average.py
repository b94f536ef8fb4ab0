"""Acting with an average of the online weights: the arithmetic, the learner's use, a resume."""

import numpy as np
import pytest
import torch

from learner.acting_average import ActingAverage
from learner.config import LearnerConfig
from learner.train import Learner
from protocol.role import RoleContext
from qattention import QAttentionConfig
from qattention.synthetic import transition_arrays

TINY = QAttentionConfig(voxel_size=8, kernels=4, head_width=16, padding="zeros", image_crop=16, rotation_resolution=30)


def test_the_average_follows_the_online_weights_with_its_decay():
    avg = ActingAverage(0.75)
    online = {"w": torch.zeros(3), "h": torch.ones(2, dtype=torch.float16)}
    assert avg.weights(online) is online  # nothing averaged yet: the online weights
    avg.update(online)
    avg.update({"w": torch.full((3,), 4.0), "h": torch.full((2,), 5.0, dtype=torch.float16)})
    out = avg.weights(online)
    assert torch.equal(out["w"], torch.full((3,), 1.0)) and out["h"].dtype == torch.float16
    assert torch.equal(out["h"], torch.full((2,), 2.0, dtype=torch.float16))  # 0.75 * 1 + 0.25 * 5
    off = ActingAverage(0.0)
    off.update(online)
    assert off.weights(online) is online and not off.state_dict()
    with pytest.raises(ValueError):
        ActingAverage(1.0)


def batch(seed):
    a = transition_arrays(3, resolution=32, seed=seed)
    a["indices"] = np.arange(3, dtype=np.int64)
    a["keys"] = np.arange(3, dtype=np.int64)
    return a


def test_the_learner_publishes_the_average_and_a_resume_keeps_it(tmp_path):
    ctx = RoleContext("run-1", "learner", tmp_path)
    learner = Learner(LearnerConfig(device="cpu", acting_average=0.5), TINY, ctx)
    first = learner.agent.weights()
    learner.train_step(batch(0))
    after_one = learner.agent.weights()
    learner.train_step(batch(1))
    online = learner.agent.weights()
    acted = learner.acting.weights(online)
    for k in online:  # 0.5 * (after update 1) + 0.5 * (after update 2)
        torch.testing.assert_close(acted[k], (0.5 * after_one[k].float() + 0.5 * online[k].float()).to(online[k].dtype))
    assert any(not torch.equal(acted[k], online[k]) for k in online)
    assert any(not torch.equal(first[k], online[k]) for k in online)
    learner.checkpoint()
    resumed = Learner(LearnerConfig(device="cpu", acting_average=0.5), TINY, ctx)
    again = resumed.acting.weights(resumed.agent.weights())
    assert all(torch.equal(again[k], acted[k]) for k in acted)

