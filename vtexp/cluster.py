"""Power analyses on a Dask cluster: ``vtexp simulate --executor dask://HOST:PORT``.

The ``cluster`` extra (``dask``, ``distributed``). A scheduler runs somewhere
(``dask scheduler``), workers join it (``dask worker tcp://HOST:8786``, each with
vtexp installed: the same version as the client's, checked here), and
:func:`connect` gives the client whose ``get_executor()`` takes the place of the
process pool in :func:`vtexp.simulate.run_power`. Workers receive the experiment's
text and SHA-256 (:class:`vtexp.simulate.ExperimentSource`), not a path, so they
need no shared file system (files an experiment refers to by path, such as stimulus
images, must exist at the same path on them; shipped codings and profiles come
with vtexp).

Anything wrong (no ``cluster`` extra, a scheduler that cannot be reached within
``timeout_s``, no workers, workers without vtexp or with another version) is one
:class:`ClusterError` before any study runs.
"""

from __future__ import annotations

import re

from . import __version__
from .errors import InputError, VtexpError

_ADDRESS = re.compile(r"^(?:dask://|tcp://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")


class ClusterError(VtexpError):
    """The cluster cannot be used (unreachable, no workers, another vtexp on them)."""

    exit_code = 2


def scheduler_address(spec: str) -> str:
    """``dask://HOST:PORT`` (or ``tcp://HOST:PORT``) → ``tcp://HOST:PORT``."""
    m = _ADDRESS.match(spec.strip())
    if m is None or not 0 < int(m.group(2)) < 65536:
        raise InputError(f"{spec!r} is not a scheduler address; give dask://HOST:PORT, "
                         "e.g. dask://127.0.0.1:8786", key="--executor")
    return f"tcp://{m.group(1)}:{m.group(2)}"


def _worker_vtexp() -> str:
    return __version__


def connect(spec: str, timeout_s: float = 5.0):
    """A ``distributed.Client`` for the scheduler ``spec`` names, checked (see module doc)."""
    address = scheduler_address(spec)
    try:
        from distributed import Client
    except ImportError as e:
        raise ClusterError(f"--executor dask:// needs Dask distributed ({e}): install the "
                           "'cluster' extra, pip install 'vtexp[cluster]'") from None
    try:
        client = Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise ClusterError(f"cannot reach the Dask scheduler at {address} within "
                           f"{timeout_s:g} s ({type(e).__name__}: {e}); start one with "
                           f"'dask scheduler' and workers with 'dask worker {address}', or "
                           "check the address") from None
    try:
        workers = client.scheduler_info().get("workers", {})
        if not workers:
            raise ClusterError(f"the Dask scheduler at {address} has no workers; start some "
                               f"with 'dask worker {address}'")
        try:
            versions = client.run(_worker_vtexp)
        except Exception as e:
            raise ClusterError(f"the workers of {address} cannot run vtexp ({e}); install "
                               f"vtexp {__version__} with the 'cluster' extra on each") from None
        other = {w: v for w, v in versions.items() if v != __version__}
        if other:
            w, v = next(iter(other.items()))
            raise ClusterError(f"worker {w} has vtexp {v}, this computer {__version__}: "
                               "install the same version on every worker")
    except BaseException:
        client.close()
        raise
    return client


def threads(client) -> int:
    """How many tasks the cluster runs at once (its workers' threads)."""
    return max(1, sum(client.nthreads().values()))
