"""Libraries the project can run without: importing one that is missing or broken is a
one-line error that says what to install (DESIGN §8)."""

from __future__ import annotations


class MissingLibraryError(Exception):
    """open3d cannot be imported (a missing system library): one line, exit code 2."""


def require_open3d():
    """The open3d module, or a one-line :class:`MissingLibraryError` that says what to install."""
    try:
        import open3d
    except (ImportError, OSError) as error:
        text = " ".join(str(error).split())
        if "libusb" in text:
            raise MissingLibraryError(
                "open3d cannot be imported: the system library libusb-1.0 is missing (Debian: apt-get install libusb-1.0-0; `bash scripts/setup.sh` installs it when run as root)"
            ) from None
        raise MissingLibraryError(f"open3d cannot be imported: {text}") from None
    return open3d
