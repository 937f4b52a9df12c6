"""stw's torch backend: the SQP of ``stw_scipy`` with expressions and their derivatives lowered to
torch programs; tensors on the CPU or a CUDA device.

Registered under the entry-point group ``stw_tui.backends`` as ``torch``, exactly as a third
party's backend would be. Loading the class does not import torch (a solve does), but fails
cleanly when torch is not installed.
"""

from importlib.util import find_spec

if find_spec("torch") is None:
    raise ImportError("the torch backend needs PyTorch: pip install 'stw-tui[torch]'")

from .backend import TorchBackend  # noqa: E402

__all__ = ["TorchBackend"]
