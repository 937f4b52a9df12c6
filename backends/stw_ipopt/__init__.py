"""IPOPT (through CasADi) as a stw solver backend, registered as ``ipopt``.

Needs the optional dependency ``casadi`` (``pip install stw-tui[ipopt]``); importing this package
without it raises ImportError, which stw reports as "backend 'ipopt' failed to load".
"""

from .backend import IpoptBackend

__all__ = ["IpoptBackend"]
