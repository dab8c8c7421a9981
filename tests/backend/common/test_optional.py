"""An interruption during an optional library's import is held until the import ends, then
raised as KeyboardInterrupt (open3d turned it into "ImportError: initialization failed")."""

from __future__ import annotations

import os
import signal

import pytest

from backend.common import optional


def test_an_interruption_inside_the_block_is_raised_after_it() -> None:
    done = []
    with pytest.raises(KeyboardInterrupt):
        with optional.interrupts_held():
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGTERM)
            done.append("the block ran to its end")
    assert done == ["the block ran to its end"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers put back


def test_an_import_interrupted_is_an_interruption_not_a_missing_library(monkeypatch) -> None:
    def interrupted_import(name: str):
        os.kill(os.getpid(), signal.SIGINT)
        raise ImportError("initialization failed")  # what open3d's extension made of a Ctrl-C

    monkeypatch.setattr(optional.importlib, "import_module", interrupted_import)
    with pytest.raises(KeyboardInterrupt):
        optional.require_open3d()
    monkeypatch.setattr(optional.importlib, "import_module", lambda name: (_ for _ in ()).throw(ImportError("libusb-1.0.so.0: cannot open")))
    with pytest.raises(optional.MissingLibraryError, match="libusb-1.0 is missing"):
        optional.require_open3d()
