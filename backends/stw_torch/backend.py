"""The torch backend: the shared SQP (stw_tui.sos.sqp: the same steps as ``stw_scipy``) with its
numbers from torch: each term and its derivatives lowered to TorchScript programs (lower.py), one
call per term over all its instances (calls.py), the gradient, Jacobians and Hessian assembled on
fixed sparse patterns (evaluate.py). KKT systems: dense LU on the device with ``linear=torch``
(linalg.py), stw_scipy's sparse solvers on the host with ``linear=scipy``. torch is imported when a
solve starts, not when the class is loaded: listing the backend's options costs nothing."""

from __future__ import annotations

from stw_scipy.sqp import ScipyBackend
from stw_tui.sos.backend import BackendOption, Capability
from stw_tui.sos.sqp import SQPBackend, SQPInner
from stw_tui.sym.errors import StwError


# The last few window problems solved, lowered (lowerings.py)
_LOWERINGS = None   # made at the first solve: the module is loaded without torch


class TorchBackend(SQPBackend):
    """SQP on torch: lowered expressions and derivatives, sparse or dense KKT solves."""

    name = "torch"
    options = (
        BackendOption("device", str, "auto", "where the tensors live (auto: cuda when available)",
                      ("auto", "cpu", "cuda")),
        BackendOption("linear", str, "auto", "KKT solves: scipy (sparse, on the host, any `solver`) or "
                      "torch (dense LU on the device); auto: torch on cuda, scipy on cpu",
                      ("auto", "scipy", "torch")),
        BackendOption("derivatives", str, "symbolic",
                      "symbolic: each term's derivatives lowered with it (fast); autograd: torch's "
                      "autograd on its value alone, independent of the compiler's derivatives "
                      "(slower; surveys' batches use symbolic)", ("symbolic", "autograd")),
        *ScipyBackend.options,
    )
    capabilities = SQPBackend.capabilities | {Capability.GPU, Capability.BATCH}
    bounded_calls = True   # its init adds a finiteness check to the SQP's: still bounded

    @classmethod
    def batch_solver(cls, size, options=None):
        """Many starts as one batch (batch.py), on cuda when torch sees one, else on the CPU."""
        from .batch import TorchBatch

        config = cls(**dict(options or {})).config   # the options, validated and parsed (once)
        device = _device(config["device"])
        return TorchBatch(size, device, config, _linear(config["linear"], device), BatchMember)

    def algebra(self, problem):
        import torch

        self.device = _device(self.config["device"])
        if self.device.type == "cpu":
            torch.set_num_threads(1)  # small batched work on 2 cores: threads cost ~50x (DESIGN.md)
        self.linear = _linear(self.config["linear"], self.device)
        if self.linear == "scipy":
            return ScipyBackend.algebra(self, problem)
        from .linalg import DenseAlgebra

        return DenseAlgebra(self.device)

    def evaluator(self, problem, algebra):
        from .lowerings import Lowerings

        global _LOWERINGS
        if _LOWERINGS is None:
            _LOWERINGS = Lowerings()
        return _LOWERINGS.get(problem, self.device, host_linear=self.linear == "scipy",
                              autograd=self.config["derivatives"] == "autograd")[0]

    def init(self, problem, state, settings) -> SQPInner:
        from .evaluate import check_finite

        if getattr(problem, "linear_objective", None) is not None:
            raise StwError("the torch backend squares every objective term: it does not take a "
                           "`maximize` or `minimize` objective yet; use `backend scipy` (or ipopt)")
        inner = super().init(problem, state, settings)
        check_finite(inner.ev, problem)
        return inner


class BatchMember(TorchBackend):
    """The torch backend of one start of a batch (batch.TorchBatch): its evaluations and, with
    the batch's ``linear=torch``, its KKT solves are computed in the batch's rounds."""

    def __init__(self, batch, job: int, **options):
        super().__init__(**options)
        self.batch, self.job = batch, job

    def algebra(self, problem):
        self.device, self.linear = self.batch.device, self.batch.linear
        if self.linear == "scipy":
            return ScipyBackend.algebra(self, problem)
        return self.batch.algebra(self.job)

    def evaluator(self, problem, algebra):
        return self.batch.evaluator(self.job, problem)


def _linear(want: str, device) -> str:
    """The KKT solves of option ``linear`` on ``device`` (auto: torch on cuda, scipy on the CPU)."""
    return ("torch" if device.type == "cuda" else "scipy") if want == "auto" else want


def _device(want: str):
    """The torch device of option ``device`` (auto: cuda when torch sees one).

    Raises:
        StwError: device=cuda without a CUDA device.
    """
    import torch

    if want == "auto":
        want = "cuda" if torch.cuda.is_available() else "cpu"
    if want == "cuda" and not torch.cuda.is_available():
        raise StwError("device=cuda, but torch sees no CUDA device (use device=cpu or auto)")
    return torch.device(want)
