"""TetGen in a child process.

TetGen aborts the whole process (``malloc(): invalid size``, SIGABRT) on some bad input, e.g. a
self-intersecting surface, instead of raising. Running it in a spawned child turns such a crash
into a clear error for the user and keeps the simulation process (and its output) alive. The child
imports only numpy and tetgen.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import tempfile

import numpy as np


def _child(conn, verts, tris, kwargs) -> None:
    # TetGen writes files of its own into the working directory when it meets bad input
    # (_skipped.face, _skipped.node): give it a private one
    with tempfile.TemporaryDirectory(prefix="simcli-tetgen-") as tmp:
        os.chdir(tmp)
        try:
            import tetgen  # noqa: PLC0415 - optional dependency, imported where used

            nodes, elems = tetgen.TetGen(verts, tris).tetrahedralize(**kwargs)[:2]
            conn.send(("ok", np.asarray(nodes, dtype=np.float64), np.asarray(elems, dtype=np.int64)))
        except Exception as e:  # noqa: BLE001 - every failure goes back to the parent as a message
            conn.send(("error", f"{type(e).__name__}: {e}", None))
        finally:
            conn.close()


def run_tetgen(verts: np.ndarray, tris: np.ndarray, **kwargs) -> tuple[str, object, object]:
    """("ok", nodes, tets), ("error", message, None), or ("crashed", exit code, None)."""
    ctx = mp.get_context("spawn")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(
        target=_child,
        args=(
            send,
            np.ascontiguousarray(verts, dtype=np.float64),
            np.ascontiguousarray(tris, dtype=np.int32),
            kwargs,
        ),
        daemon=True,
    )
    proc.start()
    send.close()
    try:
        msg = recv.recv()  # before join: a large result would fill the pipe
    except EOFError:
        msg = None
    proc.join()
    recv.close()
    if msg is None:
        return "crashed", proc.exitcode, None
    return msg
