"""The dataclass path to JSON: :func:`ftc_verify.jsonable.fields_dict` and its declarations."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from ftc_verify.jsonable import OMIT, dumps, fields_dict, renamed


@dataclass(frozen=True)
class _Inner:
    label: str
    weight: float


@dataclass(frozen=True)
class _WithToDict:
    secret: str

    def to_dict(self) -> dict[str, str]:
        return {"shown": self.secret.upper()}


@dataclass(frozen=True)
class _Outer:
    name: str
    matrix: np.ndarray
    hidden: np.ndarray = field(default_factory=lambda: np.zeros(2), metadata=OMIT)
    pairs: tuple[tuple[float, float], ...] = ()
    estimate: float | None = field(default=None, metadata=renamed("float_estimate"))
    inner: _Inner | None = None
    many: tuple[_Inner, ...] = ()
    custom: _WithToDict | None = None
    table: dict[str, object] = field(default_factory=dict)

    JSON_PROPERTIES = ("size",)

    @property
    def size(self) -> int:
        return int(self.matrix.size)


def test_fields_in_order_with_omitted_renamed_nested_and_properties() -> None:
    obj = _Outer("a", np.array([[1.0, np.inf]]), pairs=((1.0, 2.0),), estimate=np.float64(-0.5),
                 inner=_Inner("i", np.float32(0.25)), many=(_Inner("x", 1.0), _Inner("y", math.nan)),
                 custom=_WithToDict("s"), table={"ok": np.bool_(True), "nested": [_Inner("z", 2.0)]})
    d = fields_dict(obj)
    assert list(d) == ["name", "matrix", "pairs", "float_estimate", "inner", "many", "custom", "table", "size"]
    assert d == {"name": "a", "matrix": [[1.0, None]], "pairs": [[1.0, 2.0]], "float_estimate": -0.5,
                 "inner": {"label": "i", "weight": 0.25},
                 "many": [{"label": "x", "weight": 1.0}, {"label": "y", "weight": None}],
                 "custom": {"shown": "S"}, "table": {"ok": True, "nested": [{"label": "z", "weight": 2.0}]},
                 "size": 2}
    assert type(d["float_estimate"]) is float and type(d["table"]["ok"]) is bool
    assert json.loads(dumps(d)) == d


def test_defaults_and_none_stay_null() -> None:
    d = fields_dict(_Outer("b", np.zeros((0, 2))))
    assert d == {"name": "b", "matrix": [], "pairs": [], "float_estimate": None, "inner": None, "many": [],
                 "custom": None, "table": {}, "size": 0}


def test_refuses_what_is_not_a_dataclass_instance_and_names_the_place_of_a_bad_value() -> None:
    with pytest.raises(TypeError, match="dataclass instance"):
        fields_dict({"a": 1})
    with pytest.raises(TypeError, match="dataclass instance"):
        fields_dict(_Inner)
    with pytest.raises(TypeError, match=r"_Outer\.table\.bad: a builtins\.object cannot be written as JSON"):
        fields_dict(_Outer("c", np.ones(1), table={"bad": object()}))


def test_results_that_are_their_fields_use_it() -> None:
    from ftc_verify.analysis.conditioning import Similarity
    from ftc_verify.analysis.crossval import ModeCheck
    from ftc_verify.analysis.verdict import VertexVerdict
    from ftc_verify.synthesis.descent import DescentResult

    vv = VertexVerdict(np.array([[0.0, 2.0], [2.0, 0.0]]), "stable", "float64", 53, 0.25, -0.5)
    assert vv.to_dict() == {"beta": [[0.0, 2.0], [2.0, 0.0]], "verdict": "stable", "method": "float64",
                            "precision_bits": 53, "seconds": 0.25, "float_abscissa": -0.5}
    sim = Similarity(np.diag([1.0, 4.0]), np.diag([1.0, 0.25]), ("scale",))
    assert sim.to_dict() == {"steps": ["scale"], "condition": pytest.approx(4.0)}
    mc = ModeCheck(1, 2, np.array([-1 + 2j, -3 + 0j]), True, math.inf, 2.5, np.array([-1j]), 2.5, True, "agree")
    assert mc.to_dict() == {"true_mode": 1, "fdi_mode": 2, "poles": [[-1.0, 2.0], [-3.0, 0.0]], "stable": True,
                            "hinf_norm": None, "linf_norm": 2.5, "control_linf_norm": 2.5, "agree": True,
                            "detail": "agree"}
    dr = DescentResult("zero", 1, np.ones(3), -0.5, 2.0, True, ((8.0, 0.1), (1.0, -0.5)), 7, 0.5)
    assert list(dr.to_dict()) == ["start", "order", "abscissa", "gain_norm", "stabilised", "history",
                                  "evaluations", "seconds"]
    assert dr.to_dict()["history"] == [[8.0, 0.1], [1.0, -0.5]]
