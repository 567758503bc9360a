import pytest

from simcli.scene.overrides import apply_overrides, parse_set


def test_parse_and_apply():
    d = {"sim": {"dt": 1.0}, "entities": [{"material": {"E": 1}}]}
    for s in (
        "sim.dt=1e-3",
        "entities.0.material.E=2.5e6",
        "sim.gravity=[0, 0, -1]",
        "output.formats=[hdf5]",
    ):
        apply_overrides(d, [parse_set(s)])
    assert d["sim"]["dt"] == 1e-3 and isinstance(d["sim"]["dt"], float)
    assert d["entities"][0]["material"]["E"] == 2.5e6
    assert d["sim"]["gravity"] == [0, 0, -1]
    assert d["output"]["formats"] == ["hdf5"]


@pytest.mark.parametrize("bad", ["sim.dt", "=3", "a..b=1"])
def test_bad_set(bad):
    with pytest.raises(ValueError):
        parse_set(bad)
