"""The one device rule that training (cDFCVAE, CycleGAN) and sampling share."""

from __future__ import annotations

import pytest
import torch

from sonar_realism.errors import ConfigError
from sonar_realism.models.device import pick_device


def test_auto_and_cpu_name_real_devices():
    assert pick_device("cpu") == torch.device("cpu")
    assert pick_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")


@pytest.mark.parametrize("name", ["tpu", "CPU", "cuda:", "cuda:x", "cuda1", ""])
def test_a_name_that_is_no_device_is_a_config_error_naming_it(name):
    with pytest.raises(ConfigError, match=f"device {name!r}: choose auto, cpu, cuda or cuda:N"):
        pick_device(name)


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
@pytest.mark.parametrize("name", ["cuda", "cuda:0"])
def test_cuda_on_a_machine_without_it_is_a_config_error(name):
    with pytest.raises(ConfigError, match="CUDA is not available"):
        pick_device(name)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_a_cuda_index_past_the_last_device_is_a_config_error():
    assert pick_device("cuda:0") == torch.device("cuda:0")
    with pytest.raises(ConfigError, match="CUDA device"):
        pick_device(f"cuda:{torch.cuda.device_count()}")
