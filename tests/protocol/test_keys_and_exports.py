from __future__ import annotations

import importlib

import pytest

import protocol
from protocol import ProtocolError, delta_key, delta_pattern, parse_delta_key, validate_id
from protocol.keys import alive_key, parse_alive_key


def test_keys():
    assert delta_key("m", "s-1") == "psr/m/delta/s-1"
    assert delta_pattern("m") == "psr/m/delta/*"
    assert parse_delta_key("psr/m/delta/s_2") == ("m", "s_2")
    assert parse_alive_key(alive_key("m", "server")) == ("m", "server")
    with pytest.raises(ProtocolError, match=r"\[A-Za-z0-9_-\]\+") as info:
        validate_id("a/b")
    assert info.value.reason == "bad_id"
    with pytest.raises(ProtocolError) as info:
        parse_delta_key("psr/m/ack/s")
    assert info.value.reason == "key_mismatch"


@pytest.mark.parametrize(
    "module",
    [
        "protocol",
        "protocol.codec",
        "protocol.keys",
        "protocol.layers",
        "protocol.messages",
        "scout_agent.delivery",
        "protocol.errors",
    ],
)
def test_all_is_honest(module):
    mod = importlib.import_module(module)
    for name in mod.__all__:
        assert hasattr(mod, name), f"{module}.__all__ lists missing {name}"


def test_package_exports_interface_names():
    for name in (
        "ProtocolError",
        "LAYERS",
        "merge_op",
        "layer_value",
        "cell_index",
        "cell_center",
        "CellDelta",
        "Ack",
        "MapRegion",
        "Status",
        "encode",
        "decode",
        "elevation_slope_deg",
    ):
        assert name in protocol.__all__


def test_the_contract_imports_no_transport_and_no_service():
    # protocol is the wire contract only: importing every module of it in a fresh interpreter loads no
    # Zenoh, no Rerun, and none of the services or their shared session code
    import pkgutil
    import subprocess
    import sys

    names = [f"protocol.{m.name}" for m in pkgutil.iter_modules(protocol.__path__)]
    code = (
        "import importlib, sys\n"
        f"for n in {names!r}: importlib.import_module(n)\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('zenoh', 'rerun', 'psrmap_common', 'scout_agent', 'map_server', 'consumer_planner', 'psrmap', 'psrmap_interop'))\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert len(names) >= 5
    assert out.stdout.strip() == "", f"protocol pulls in {out.stdout.strip()}"
