"""Who may open the debugger: the Host and Origin rules checked on every HTTP request and
websocket handshake, before viser sees it (viewer/guard.py applies them).

A web page in the user's browser can open a websocket to any address, 127.0.0.1 included,
and the browser then sends the page's own origin in the `Origin` header. So:

- `Host` must name this machine: an IP address (a literal cannot be re-pointed by DNS),
  `localhost`, this machine's host name, the `--host` given, or a host of `--allow-origin`.
  A hostile name that resolves to 127.0.0.1 (DNS rebinding) is refused.
- `Origin`, when present, must be the page the debugger itself served, i.e. `http(s)://`
  followed by the request's own `Host` (an SSH tunnel or a port forward keeps them equal),
  or one of `--allow-origin`. `Origin: null` (sandboxed frames, files) is refused.
- No `Origin` at all is a client that is not a web page (a script on this machine, which
  could read the same files directly); it is admitted and its messages are checked like any
  other (viewer/inbound.py).
"""

from __future__ import annotations

import dataclasses
import ipaddress
import socket
import urllib.parse
from collections.abc import Callable, Mapping

LOOPBACK_NAMES = ("localhost",)
DEFAULT_MAX_UPLOAD_BYTES = 16 * 2**20


class OriginError(ValueError):
    """An `--allow-origin` value that is not `http(s)://host[:port]`."""


@dataclasses.dataclass(frozen=True)
class AccessSettings:
    """What the debugger's server admits besides its own pages.

    `allowed_origins`: further origins (`https://host[:port]`, e.g. a reverse proxy's) whose
    pages may connect; their hosts are admitted as `Host` too. `share`: handle viser's share
    requests (a public tunnel through viser's relay; off: they are dropped).
    `max_upload_bytes`: the largest file an upload control accepts."""

    allowed_origins: tuple[str, ...] = ()
    share: bool = False
    max_upload_bytes: int = DEFAULT_MAX_UPLOAD_BYTES

    def __post_init__(self) -> None:
        object.__setattr__(self, "allowed_origins", tuple(normalize_origin(o) for o in self.allowed_origins))


def normalize_origin(origin: str) -> str:
    """`scheme://host[:port]` in lower case without a default port; OriginError otherwise."""
    parsed = urllib.parse.urlsplit(origin.strip())
    if parsed.scheme not in ("http", "https") or not parsed.hostname:
        raise OriginError(f"{origin!r} is not an origin: expected http://HOST[:PORT] or https://HOST[:PORT]")
    if parsed.path not in ("", "/") or parsed.query or parsed.fragment or parsed.username or parsed.password:
        raise OriginError(f"{origin!r} is not an origin: no path, query or user (http://HOST[:PORT])")
    try:
        port = parsed.port
    except ValueError:
        raise OriginError(f"{origin!r} has a bad port") from None
    host = parsed.hostname.lower()
    if ":" in host:
        host = f"[{host}]"
    default = {"http": 80, "https": 443}[parsed.scheme]
    return f"{parsed.scheme}://{host}" + (f":{port}" if port not in (None, default) else "")


def host_name(host_header: str) -> str | None:
    """The host of a `Host` header value (`name[:port]`, `[v6]:port`), lower case, without
    a trailing dot; None when malformed."""
    value = host_header.strip().lower()
    if value.startswith("["):
        end = value.find("]")
        if end < 0 or (value[end + 1 :] and not (value[end + 1] == ":" and value[end + 2 :].isdigit())):
            return None
        return value[1:end] or None
    name, _, port = value.partition(":")
    if port and not port.isdigit():
        return None
    name = name.rstrip(".")
    return name or None


def is_ip_literal(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def is_loopback_bind(host: str) -> bool:
    """Whether `--host` serves this machine only (127.0.0.0/8, ::1 or localhost)."""
    name = host.strip("[]").lower()
    if name in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


@dataclasses.dataclass(frozen=True)
class OriginPolicy:
    """The Host and Origin rules for a server bound to `bind_host` (module docstring).
    `share_origin`: the public share address while a tunnel is open (None: none)."""

    bind_host: str
    allowed_origins: tuple[str, ...] = ()
    share_origin: Callable[[], str | None] | None = None
    machine_names: tuple[str, ...] = dataclasses.field(default_factory=lambda: (socket.gethostname().lower(),))

    def _share(self) -> str | None:
        url = self.share_origin() if self.share_origin is not None else None
        if not url:
            return None
        try:
            return normalize_origin(url)
        except OriginError:
            return None

    def host_allowed(self, name: str) -> bool:
        if is_ip_literal(name) or name in LOOPBACK_NAMES or name in self.machine_names:
            return True
        if name == self.bind_host.strip("[]").lower().rstrip("."):
            return True
        origins = self.allowed_origins + ((share,) if (share := self._share()) else ())
        return any(urllib.parse.urlsplit(o).hostname == name for o in origins)

    def refusal(self, headers: Mapping[str, str], *, get_all: Callable[[str], list[str]] | None = None, websocket: bool) -> str | None:
        """Why a request with these headers is refused (one line), or None to admit it.
        `get_all`: all values of a header (a repeated Host or Origin is refused)."""
        if get_all is not None and (len(get_all("Host")) > 1 or len(get_all("Origin")) > 1):
            return "repeated Host or Origin header"
        host_header = headers.get("Host")
        if host_header is None:
            return "no Host header"
        name = host_name(host_header)
        if name is None:
            return f"malformed Host {host_header!r}"
        if not self.host_allowed(name):
            return f"Host {host_header!r} is not this machine (add --allow-origin for a proxy's name)"
        origin = headers.get("Origin")
        if origin is None:
            return None  # not a web page (module docstring)
        if not websocket:
            return None  # plain HTTP: the page and its files; the browser keeps a foreign page from reading them
        try:
            normalized = normalize_origin(origin)
            own = {normalize_origin(f"{scheme}://{host_header.strip()}") for scheme in ("http", "https")}
        except OriginError:
            return f"Origin {origin!r} is not allowed"
        share = self._share()
        if normalized in own or normalized in self.allowed_origins or normalized == share:
            return None
        return f"Origin {origin!r} is not this debugger's page (add --allow-origin {normalized} to admit it)"
