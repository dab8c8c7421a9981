"""The Host and Origin rules (viewer/access.py) on the headers browsers and proxies send."""

from __future__ import annotations

import pytest

from viewer.access import AccessSettings, OriginError, OriginPolicy, host_name, is_loopback_bind, normalize_origin


def _refusal(policy: OriginPolicy, host: str | None, origin: str | None = None, *, websocket: bool = True) -> str | None:
    headers = {k: v for k, v in (("Host", host), ("Origin", origin)) if v is not None}
    return policy.refusal(headers, websocket=websocket)


LOCAL = OriginPolicy(bind_host="127.0.0.1", machine_names=("slambox",))


@pytest.mark.parametrize(
    ("host", "origin"),
    [
        ("127.0.0.1:8080", "http://127.0.0.1:8080"),
        ("localhost:8080", "http://localhost:8080"),
        ("LOCALHOST:8080", "http://localhost:8080"),
        ("[::1]:8080", "http://[::1]:8080"),
        ("localhost:9000", "http://localhost:9000"),  # an SSH tunnel: ssh -L 9000:localhost:8080
        ("slambox:8080", "http://slambox:8080"),
        ("127.0.0.1:8080", None),  # a script on this machine, not a page
        ("localhost.:8080", "http://localhost.:8080"),
    ],
)
def test_the_debuggers_own_page_is_admitted(host: str, origin: str | None) -> None:
    assert _refusal(LOCAL, host, origin) is None


@pytest.mark.parametrize(
    ("host", "origin", "words"),
    [
        ("127.0.0.1:8080", "http://evil.example.com", "Origin"),
        ("127.0.0.1:8080", "https://evil.example.com:8080", "Origin"),
        ("127.0.0.1:8080", "http://localhost:8080", "Origin"),  # another origin than the page's own
        ("127.0.0.1:8080", "null", "Origin"),
        ("127.0.0.1:8080", "http://127.0.0.1:8081", "Origin"),
        ("evil.example.com:8080", "http://evil.example.com:8080", "Host"),  # DNS rebinding
        ("evil.example.com:8080", None, "Host"),
        (None, None, "no Host"),
        ("[::1:8080", None, "malformed"),
        ("127.0.0.1:http", None, "malformed"),
        ("127.0.0.1:99999", "http://127.0.0.1:99999", "Origin"),
    ],
)
def test_other_pages_and_names_are_refused(host: str | None, origin: str | None, words: str) -> None:
    why = _refusal(LOCAL, host, origin)
    assert why is not None and words in why


def test_a_repeated_header_is_refused() -> None:
    headers = {"Host": "127.0.0.1:8080"}
    why = LOCAL.refusal(headers, get_all=lambda name: ["a", "b"] if name == "Origin" else ["127.0.0.1:8080"], websocket=True)
    assert why == "repeated Host or Origin header"


def test_plain_page_requests_check_the_host_only() -> None:
    assert _refusal(LOCAL, "127.0.0.1:8080", "http://evil.example.com", websocket=False) is None
    assert _refusal(LOCAL, "evil.example.com:8080", None, websocket=False) is not None


def test_allowed_origins_and_their_hosts() -> None:
    settings = AccessSettings(allowed_origins=("HTTPS://Proxy.Lab.Example:443", "http://10.0.0.5:9000/"))
    assert settings.allowed_origins == ("https://proxy.lab.example", "http://10.0.0.5:9000")
    policy = OriginPolicy(bind_host="127.0.0.1", allowed_origins=settings.allowed_origins, machine_names=())
    assert _refusal(policy, "proxy.lab.example", "https://proxy.lab.example") is None
    assert _refusal(policy, "127.0.0.1:8080", "https://proxy.lab.example") is None  # a proxy that rewrites Host
    assert _refusal(policy, "127.0.0.1:8080", "https://proxy.lab.example:8443") is not None
    assert _refusal(policy, "other.lab.example", None) is not None


def test_a_share_address_is_admitted_while_the_tunnel_is_open() -> None:
    url: list[str | None] = [None]
    policy = OriginPolicy(bind_host="127.0.0.1", share_origin=lambda: url[0], machine_names=())
    assert _refusal(policy, "abc.share.example", "https://abc.share.example") is not None
    url[0] = "https://abc.share.example"
    assert _refusal(policy, "abc.share.example", "https://abc.share.example") is None


def test_every_interface_admits_addresses_and_the_machine_name() -> None:
    policy = OriginPolicy(bind_host="0.0.0.0", machine_names=("slambox",))
    assert _refusal(policy, "192.168.1.7:8080", "http://192.168.1.7:8080") is None
    assert _refusal(policy, "slambox:8080", "http://slambox:8080") is None
    assert _refusal(policy, "attacker.example:8080", "http://attacker.example:8080") is not None
    named = OriginPolicy(bind_host="slam.lab.example", machine_names=())
    assert _refusal(named, "slam.lab.example:8080", "http://slam.lab.example:8080") is None


@pytest.mark.parametrize("bad", ["lab.example", "ftp://lab.example", "https://lab.example/app", "https://user@lab.example", "https://lab.example:99999", "http://"])
def test_bad_allowed_origins_are_errors(bad: str) -> None:
    with pytest.raises(OriginError):
        normalize_origin(bad)


def test_host_names_and_loopback_binds() -> None:
    assert host_name("Example.ORG.:80") == "example.org"
    assert host_name("[::1]:8080") == "::1" and host_name("[::1]") == "::1"
    assert host_name("[::1]x") is None and host_name(":80") is None
    assert is_loopback_bind("127.0.0.1") and is_loopback_bind("::1") and is_loopback_bind("localhost") and is_loopback_bind("127.0.1.1")
    assert not is_loopback_bind("0.0.0.0") and not is_loopback_bind("::") and not is_loopback_bind("192.168.1.7")
