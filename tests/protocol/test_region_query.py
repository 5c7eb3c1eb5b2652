"""Region query parameters: what a client writes is what a server parses back."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.errors import ProtocolError
from protocol.messages import RegionQuery


def test_numpy_scalars_round_trip_as_plain_numbers() -> None:
    q = RegionQuery(np.float64(-0.9), np.float32(1.5), np.int64(3), 4.25, ("slip",), ("value", "n"))
    text = q.to_parameters()
    assert "np." not in text
    back = RegionQuery.parse(text)
    assert (back.x0, back.y0, back.x1, back.y1) == (pytest.approx(-0.9), 1.5, 3.0, 4.25)
    assert back.layers == ("slip",) and back.stats == ("value", "n")


def test_bad_number_names_the_field() -> None:
    with pytest.raises(ProtocolError, match="x0"):
        RegionQuery.parse("x0=abc;y0=0;x1=1;y1=1")
