"""Unit tests of ftc_verify.model.files: loading, saving, round trips, error messages."""

from __future__ import annotations

import copy
import os
import re

import numpy as np
import pytest
import tomli_w

from ftc_verify.model import files as problem_files
from ftc_verify.errors import ProblemFileError, ValidationError
from ftc_verify.model.system import FTCSystem, JointChain
from ftc_verify.model.files import dump_system, load_system, save_system
from ftc_verify.controllers.files import check_gains, load_controller, load_gains, save_gains

MODE_KEYS = ("A", "B", "C", "D", "A1", "A2", "B1", "B2")

BASE_DOC = {
    "name": "unit",
    "chain": {
        "alpha": [[-0.5, 0.5], [1.0, -1.0]],
        "beta_min": [[0.0, 2.0], [2.5, 0.0]],
        "beta_max": [[0.0, 3.0], [3.5, 0.0]],
    },
    "mode": [
        {"A": [[-1.0, 0.0], [0.0, -2.0]], "B": [[1.0], [0.0]], "C": [[1.0, 1.0]], "D": [[0.5], [0.5]]},
        {"A": [[-1.5, 0.0], [0.0, -2.5]], "B": [[0.5], [0.0]], "C": [[1.0, 1.0]], "D": [[0.5], [1.0]]},
    ],
}

GAINS_DOC = {"name": "g", "gain": [{"K": [[1.0, 2.0]]}, {"K": [[3.0, 4.0]]}]}


def write_doc(path, doc):
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    return path


def doc(**changes):
    d = copy.deepcopy(BASE_DOC)
    for k, v in changes.items():
        d[k] = v
    return d


def expect_file_error(loader, path, *fragments):
    with pytest.raises(ProblemFileError) as info:
        loader(path)
    msg = str(info.value)
    assert path.name in msg, msg
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    return msg


def assert_systems_identical(a: FTCSystem, b: FTCSystem):
    assert a.name == b.name
    assert len(a.modes) == len(b.modes)
    for ma, mb in zip(a.modes, b.modes):
        for key in MODE_KEYS:
            va, vb = getattr(ma, key), getattr(mb, key)
            assert (va is None) == (vb is None), key
            if va is not None:
                assert va.shape == vb.shape and np.array_equal(va, vb), key
    for key in ("alpha", "beta_min", "beta_max"):
        assert np.array_equal(getattr(a.chain, key), getattr(b.chain, key)), key
    assert a.chain.fault_during_delay == b.chain.fault_during_delay
    assert a == b


# ============================================================================ the paper example
def test_paper_example_loads(paper_system):
    s = paper_system
    assert s.m == 2
    assert s.dims == (2, 2, 1, 1)
    assert s.uncertain
    # Numbers of Section VI of the paper.
    np.testing.assert_array_equal(s.chain.alpha, [[-0.5, 0.5], [1.0, -1.0]])
    # beta[fdi][true]: beta_12 in [2, 3], beta_21 in [2.5, 3.5]
    assert (s.chain.beta_min[0, 1], s.chain.beta_max[0, 1]) == (2.0, 3.0)
    assert (s.chain.beta_min[1, 0], s.chain.beta_max[1, 0]) == (2.5, 3.5)
    for md in s.modes:
        np.testing.assert_array_equal(md.A, [[1.0, 0.0], [0.0, 0.8]])
        np.testing.assert_array_equal(md.C, [[1.0, 2.0]])
        for key in ("A1", "A2", "B1", "B2"):
            np.testing.assert_array_equal(getattr(md, key), 0.1 * np.eye(2))
    np.testing.assert_array_equal(s.modes[0].B, [[0.0, 1.0], [-0.25, 0.25]])
    np.testing.assert_array_equal(s.modes[1].B, [[0.0, 0.2], [-0.25, 0.05]])
    np.testing.assert_array_equal(s.modes[0].D, [[0.5], [0.5]])
    np.testing.assert_array_equal(s.modes[1].D, [[0.5], [1.0]])


def test_paper_gains_load(paper_system, paper_gains):
    assert len(paper_gains) == 2
    np.testing.assert_array_equal(paper_gains[0], [[2.4563, 29.4954], [-21.0010, -7.5161]])
    np.testing.assert_array_equal(paper_gains[1], [[1.9998, 24.5445], [-12.4093, -3.2219]])
    assert len(check_gains(paper_system, paper_gains)) == 2


# ============================================================================ round trips
def test_paper_round_trip(paper_system, tmp_path):
    out = tmp_path / "copy.toml"
    save_system(paper_system, out)
    again = load_system(out)
    assert_systems_identical(paper_system, again)
    # second save is byte-identical (the text is a fixed point)
    out2 = tmp_path / "copy2.toml"
    save_system(again, out2)
    assert out.read_text() == out2.read_text()


TRICKY = [0.1, 1 / 3, 1e-300, -2.5e-17, 1e15, 123456789.123456789, 5e-324, -0.0, 2.0 / 7.0]


def tricky_system(with_uncertainty: bool) -> FTCSystem:
    t = TRICKY
    m1 = {"A": [[t[0], t[1]], [t[2], t[3]]], "B": [[t[4]], [t[5]]], "C": [[t[6], t[7]]], "D": [[t[8]], [0.1]]}
    m2 = {"A": [[1 / 3, -0.1], [0.7, 1e-300]], "B": [[0.3], [2 / 3]], "C": [[1.1, 2.2]], "D": [[1e-10], [3.3]]}
    if with_uncertainty:
        m1.update(A1=[[0.1], [1 / 3]], A2=[[1e-300, 0.2]], B1=[[0.1, 0.3], [0.0, 1 / 7]], B2=[[0.1], [1 / 3]])
        m2.update(A1=[[0.2], [1 / 9]], A2=[[0.3, 0.4]], B1=[[0.1, 0.3], [0.0, 1 / 11]], B2=[[0.5], [1 / 13]])
    return FTCSystem.from_arrays(
        name="tricky \"quoted\" name",
        modes=[m1, m2],
        alpha=[[-1 / 3, 1 / 3], [0.1, -0.1]],
        beta_min=[[0.0, 0.1], [1 / 3, 0.0]],
        beta_max=[[0.0, 0.3], [2 / 3, 0.0]],
    )


@pytest.mark.parametrize("with_uncertainty", [False, True])
def test_system_round_trip_exact_floats(tmp_path, with_uncertainty):
    s = tricky_system(with_uncertainty)
    p = tmp_path / "sys.toml"
    save_system(s, p)
    back = load_system(p)
    assert_systems_identical(s, back)
    assert back.uncertain == with_uncertainty
    # and a second cycle
    save_system(back, p)
    assert_systems_identical(s, load_system(p))


@pytest.mark.parametrize("name", [None, "my gains"])
def test_gains_round_trip_exact_floats(tmp_path, name):
    gains = (np.array([[0.1, 1 / 3], [1e-300, -7.0]]), np.array([[2 / 3, -1e15], [-0.0, 123456789.123456789]]))
    p = tmp_path / "gains.toml"
    save_gains(gains, p, name=name)
    back = load_gains(p)
    assert len(back) == 2
    for a, b in zip(gains, back):
        assert a.shape == b.shape and np.array_equal(a, b)


def test_load_without_name_uses_file_stem(tmp_path):
    d = doc()
    del d["name"]
    s = load_system(write_doc(tmp_path / "stemname.toml", d))
    assert s.name == "stemname"


def test_fault_during_delay_variant_survives_save(tmp_path):
    """Saving the named variant must not silently turn it into the paper's model."""
    base = tricky_system(False)
    chain = JointChain(base.chain.alpha, base.chain.beta_min, base.chain.beta_max, fault_during_delay=True)
    s = FTCSystem(base.name, base.modes, chain)
    p = tmp_path / "variant.toml"
    try:
        save_system(s, p)
    except ValidationError:
        return  # refusing to save an unrepresentable model is acceptable
    back = load_system(p)
    assert back.chain.fault_during_delay, "fault_during_delay=True was dropped by save/load"


# ============================================================================ unknown / missing keys
def test_unknown_top_level_key(tmp_path):
    p = write_doc(tmp_path / "top.toml", doc(solver="clarabel"))
    expect_file_error(load_system, p, "solver", "top level")


def test_unknown_chain_key(tmp_path):
    d = doc()
    d["chain"]["gamma"] = 0.8
    expect_file_error(load_system, write_doc(tmp_path / "chain.toml", d), "[chain]", "gamma")


def test_unknown_mode_key_names_table_index(tmp_path):
    d = doc()
    d["mode"][1]["E"] = [[1.0]]
    msg = expect_file_error(load_system, write_doc(tmp_path / "mode.toml", d), "'E'")
    assert "mode[2]" in msg


def test_unknown_gain_key_names_table_index(tmp_path):
    d = copy.deepcopy(GAINS_DOC)
    d["gain"][1]["L"] = [[1.0]]
    msg = expect_file_error(load_gains, write_doc(tmp_path / "g.toml", d), "'L'")
    assert "gain[2]" in msg


def test_unknown_gains_top_level_key(tmp_path):
    d = copy.deepcopy(GAINS_DOC)
    d["gamma"] = 0.8
    expect_file_error(load_gains, write_doc(tmp_path / "g.toml", d), "gamma")


@pytest.mark.parametrize("key", ["alpha", "beta_min", "beta_max"])
def test_missing_chain_key(tmp_path, key):
    d = doc()
    del d["chain"][key]
    expect_file_error(load_system, write_doc(tmp_path / "c.toml", d), "[chain]", key)


@pytest.mark.parametrize("key", ["A", "B", "C", "D"])
def test_missing_mode_key(tmp_path, key):
    d = doc()
    del d["mode"][1][key]
    msg = expect_file_error(load_system, write_doc(tmp_path / "m.toml", d), f"'{key}'")
    assert "mode[2]" in msg


@pytest.mark.parametrize("table", ["chain", "mode"])
def test_missing_table(tmp_path, table):
    d = doc()
    del d[table]
    expect_file_error(load_system, write_doc(tmp_path / "t.toml", d), table)


def test_missing_gain_K(tmp_path):
    p = tmp_path / "noK.toml"
    p.write_text("[[gain]]\nK = [[1.0]]\n[[gain]]\n", encoding="utf-8")
    msg = expect_file_error(load_gains, p, "'K'")
    assert "gain[2]" in msg


def test_gains_file_without_gain_tables(tmp_path):
    expect_file_error(load_gains, write_doc(tmp_path / "empty.toml", {"name": "x"}), "gain")


def test_name_must_be_string(tmp_path):
    expect_file_error(load_system, write_doc(tmp_path / "n.toml", doc(name=3)), "name", "3")
    expect_file_error(load_gains, write_doc(tmp_path / "g.toml", GAINS_DOC | {"name": 3}), "name", "3")


def test_controller_file_records_its_literals_and_default_name(tmp_path):
    """Both loaders read through ``model.files.read_named``: the decimal texts kept, the
    stem the default name."""
    d = {key: value for key, value in GAINS_DOC.items() if key != "name"}
    p = tmp_path / "stem.toml"
    p.write_text(tomli_w.dumps(d).replace("2.0", "2.00"), encoding="utf-8")
    ctrl = load_controller(p)
    assert ctrl.name == "stem" and ctrl.literals[2.0] == ("2.00",)


# ============================================================================ unreadable files
@pytest.mark.parametrize("loader", [load_system, load_gains])
def test_not_toml(tmp_path, loader):
    p = tmp_path / "broken.toml"
    p.write_text("this is = = not toml [[[\n", encoding="utf-8")
    expect_file_error(loader, p, "TOML")


@pytest.mark.parametrize("loader", [load_system, load_gains])
def test_not_utf8(tmp_path, loader):
    p = tmp_path / "binary.toml"
    p.write_bytes(b"name = \"\xff\xfe\"\n")
    expect_file_error(loader, p)


@pytest.mark.parametrize("loader", [load_system, load_gains])
def test_missing_file(tmp_path, loader):
    expect_file_error(loader, tmp_path / "does_not_exist.toml")


@pytest.mark.parametrize("loader", [load_system, load_gains])
def test_directory(tmp_path, loader):
    d = tmp_path / "a_folder.toml"
    d.mkdir()
    expect_file_error(loader, d, "directory")


# ============================================================================ validation inside files
def test_mode_shape_error_names_file_and_index(tmp_path):
    d = doc()
    d["mode"][1]["A"] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    msg = expect_file_error(load_system, write_doc(tmp_path / "shape.toml", d))
    assert "mode[2].A" in msg and "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]" in msg


def test_nan_in_file_names_file_index_and_value(tmp_path):
    p = tmp_path / "nan.toml"
    p.write_text(
        'name = "x"\n[chain]\nalpha = [[-0.5, 0.5], [1.0, -1.0]]\n'
        "beta_min = [[0.0, 2.0], [2.5, 0.0]]\nbeta_max = [[0.0, 3.0], [3.5, 0.0]]\n"
        "[[mode]]\nA = [[-1.0]]\nB = [[1.0]]\nC = [[1.0]]\nD = [[1.0]]\n"
        "[[mode]]\nA = [[-1.0]]\nB = [[1.0]]\nC = [[1.0]]\nD = [[nan]]\n",
        encoding="utf-8",
    )
    msg = expect_file_error(load_system, p, "nan")
    assert "mode[2].D" in msg


def test_inf_in_gains_file(tmp_path):
    p = tmp_path / "inf.toml"
    p.write_text("[[gain]]\nK = [[1.0]]\n[[gain]]\nK = [[-inf]]\n", encoding="utf-8")
    msg = expect_file_error(load_gains, p, "inf")
    assert "gain[2]" in msg


def test_chain_error_names_file(tmp_path):
    d = doc()
    d["chain"]["alpha"] = [[0.5, -0.5], [1.0, -1.0]]
    expect_file_error(load_system, write_doc(tmp_path / "alpha.toml", d), "chain.alpha", "-0.5")


def test_dimension_mismatch_names_file_and_mode(tmp_path):
    d = doc()
    d["mode"][1]["B"] = [[1.0, 2.0], [0.0, 1.0]]  # nu = 2 while mode 1 has nu = 1
    msg = expect_file_error(load_system, write_doc(tmp_path / "dims.toml", d), "nu")
    assert re.search(r"mode[\[ ]2", msg), msg


def test_mode_count_mismatch(tmp_path):
    d = doc()
    d["mode"].append(copy.deepcopy(d["mode"][0]))
    expect_file_error(load_system, write_doc(tmp_path / "three.toml", d), "3", "2")


def test_quoted_numbers_in_file_are_rejected(tmp_path):
    """A string where a number belongs must be an error, not silently converted."""
    d = doc()
    d["mode"][0]["A"] = [["-1.0", "0.0"], ["0.0", "-2.0"]]
    msg = expect_file_error(load_system, write_doc(tmp_path / "quoted.toml", d))
    assert "mode[1].A" in msg


def test_check_gains(tmp_path):
    s = load_system(write_doc(tmp_path / "s.toml", doc()))  # n = 2, nu = 1
    with pytest.raises(ValidationError) as info:
        check_gains(s, [np.ones((1, 2))])
    assert "1 entries given" in str(info.value) and "2 modes" in str(info.value)
    with pytest.raises(ValidationError) as info:
        check_gains(s, [np.ones((1, 2)), np.ones((2, 2))], source="my.toml")
    msg = str(info.value)
    assert msg.startswith("my.toml") and "gain[2].K" in msg and "expected shape 1 x 2" in msg and "got 2 x 2" in msg


# ============================================================================ atomic writing
def test_save_leaves_no_temporary_files(tmp_path, paper_system, paper_gains):
    save_system(paper_system, tmp_path / "sys.toml")
    save_system(paper_system, tmp_path / "sys.toml")  # overwrite
    save_gains(paper_gains, tmp_path / "gains.toml", name="k")
    assert sorted(os.listdir(tmp_path)) == ["gains.toml", "sys.toml"]
    assert load_system(tmp_path / "sys.toml") == paper_system


def test_failed_save_keeps_old_file_and_cleans_up(tmp_path, monkeypatch, paper_system):
    target = tmp_path / "sys.toml"
    target.write_text("old contents\n", encoding="utf-8")

    def boom(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(problem_files.os, "replace", boom)
    with pytest.raises(OSError):
        save_system(paper_system, target)
    monkeypatch.undo()
    assert target.read_text(encoding="utf-8") == "old contents\n"
    assert os.listdir(tmp_path) == ["sys.toml"]


def test_save_into_missing_folder_is_a_problem_file_error(tmp_path, paper_system):
    target = tmp_path / "no" / "such" / "folder" / "sys.toml"
    with pytest.raises(ProblemFileError) as info:
        save_system(paper_system, target)
    assert "sys.toml" in str(info.value)
    assert not (tmp_path / "no").exists()


def test_dump_system_is_valid_toml_with_documented_keys(paper_system):
    import tomllib

    d = tomllib.loads(dump_system(paper_system))
    assert set(d) == {"name", "chain", "mode"}
    assert set(d["chain"]) == {"alpha", "beta_min", "beta_max"}
    assert len(d["mode"]) == 2 and set(d["mode"][0]) == set(MODE_KEYS)
