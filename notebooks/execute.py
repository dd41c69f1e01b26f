"""Build and execute the notebooks: each ``NAME.py`` (jupytext percent format, the source)
becomes ``NAME.ipynb`` with its outputs, executed in this folder by nbclient.

Usage::

    python notebooks/execute.py [NAME ...] [--size small|full] [--timeout S]

``--size`` sets ``HELI_UQ_NOTEBOOK_SIZE`` for the kernel (see ``_setup.py``).  The tests
(``tests/test_notebooks.py``) call :func:`execute` at the small size into a temporary
folder and check that the stored ``.ipynb`` holds the same code as its ``.py``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

import jupytext
import nbformat
from nbclient import NotebookClient

HERE = pathlib.Path(__file__).resolve().parent
#: The notebooks, in reading order.
NOTEBOOKS = ("quickstart", "posterior_bands", "identifiability", "discovery", "hybrid")


def execute(name: str, size: str = "full", out: pathlib.Path | None = None, timeout: int = 3600,
            workdir: pathlib.Path | None = None):
    """Execute ``NAME.py`` as a notebook in ``workdir`` (default: this folder; the notebook
    writes its files under ``workdir/out/``) and write it with its outputs to ``out``
    (default ``NAME.ipynb`` here); returns the notebook.  A failing cell raises
    ``nbclient.exceptions.CellExecutionError`` naming the cell and the error."""
    nb = jupytext.read(HERE / f"{name}.py")
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.metadata["jupytext"] = {"formats": "ipynb,py:percent"}
    # The kernel inherits this environment: the size, and inline figures (a headless run
    # may have set MPLBACKEND=Agg, which would drop them from the outputs).
    kernel_env = {"HELI_UQ_NOTEBOOK_SIZE": size, "MPLBACKEND": "module://matplotlib_inline.backend_inline",
                  "PYTHONPATH": os.pathsep.join(filter(None, [str(HERE), os.environ.get("PYTHONPATH")]))}
    previous = {k: os.environ.get(k) for k in kernel_env}
    os.environ.update(kernel_env)
    try:
        NotebookClient(nb, timeout=timeout, kernel_name="python3",
                       resources={"metadata": {"path": str(workdir or HERE)}}).execute()
    finally:
        for key, value in previous.items():
            if value is None:
                os.environ.pop(key)
            else:
                os.environ[key] = value
    target = out or HERE / f"{name}.ipynb"
    tmp = target.with_suffix(".ipynb.tmp")
    nbformat.write(nb, tmp)
    os.replace(tmp, target)
    return nb


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", metavar="NAME", help=f"default: all of {', '.join(NOTEBOOKS)}")
    ap.add_argument("--size", choices=("small", "full"), default="full")
    ap.add_argument("--timeout", type=int, default=3600, help="per cell [s]")
    ap.add_argument("--out-dir", default=None, help="write the executed notebooks here (default: next to "
                                                    "their .py, the stored ones)")
    args = ap.parse_args(argv)
    unknown = sorted(set(args.names) - set(NOTEBOOKS))
    if unknown:
        ap.error(f"unknown notebook(s) {', '.join(unknown)}; expected some of {', '.join(NOTEBOOKS)}")
    for name in args.names or NOTEBOOKS:
        t0 = time.perf_counter()
        out = None
        if args.out_dir:
            out = pathlib.Path(args.out_dir) / f"{name}.ipynb"
            out.parent.mkdir(parents=True, exist_ok=True)
        execute(name, args.size, out=out, timeout=args.timeout)
        print(f"{name}.ipynb: executed at size {args.size} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
