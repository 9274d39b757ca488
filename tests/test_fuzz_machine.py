"""Property tests of the machine TOML: any mutation of a preset loads as a consistent Machine or
is refused with an InputError naming file and field; never another exception.  Seeded and
derandomized, a few seconds in CI."""
import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtcomp import InputError
from mtcomp._io import dump_toml
from mtcomp.machine import RESOLUTIONS, load_machine

FUZZ = settings(max_examples=120, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

scalars = st.one_of(st.booleans(), st.integers(min_value=-2**70, max_value=2**70),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6),
                    st.sampled_from(["X", "C", "tool", "workpiece", "linear", "rotary", 1e-6, 5e-6, 1e-5]))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4), max_leaves=6)
AXIS_KEYS = ["name", "kind", "side", "direction", "location", "limits", "resolution", "speed"]
HEAD_KEYS = ["name", "description", "sources", "tool_point", "tool_axis", "k"]
PRESETS = ["robonano-ui", "robonano-a0ib", "vmc-moving-column"]


@st.composite
def mutated_machine(draw):
    d = load_machine(draw(st.sampled_from(PRESETS))).to_dict()
    for _ in range(draw(st.integers(1, 3))):
        where = draw(st.sampled_from(["axis", "machine", "order", "top"]))
        axes_ok = isinstance(d.get("axis"), list) and d["axis"] and all(isinstance(a, dict) for a in d["axis"])
        if where in ("axis", "order") and not axes_ok or where == "machine" and not isinstance(d.get("machine"), dict):
            where = "top"
        if where == "axis":
            ax = d["axis"][draw(st.integers(0, len(d["axis"]) - 1))]
            key = draw(st.sampled_from(AXIS_KEYS))
            if draw(st.booleans()) and key in ax:
                del ax[key]
            else:
                ax[key] = draw(values)
        elif where == "machine":
            d["machine"][draw(st.sampled_from(HEAD_KEYS))] = draw(values)
        elif where == "order":
            d["axis"] = draw(st.permutations(d["axis"]))
        else:
            d[draw(st.sampled_from(["axis", "machine", "extra"]))] = draw(values)
    return d


@FUZZ
@given(mutated_machine())
def test_machine_toml_never_crashes(tmp_path, d):
    f = tmp_path / "m.toml"
    try:
        f.write_text(dump_toml(d))
    except Exception:  # noqa: BLE001 - not representable in TOML: not an input anyone can write
        return
    try:
        m = load_machine(f)
    except InputError as exc:
        assert str(f) in str(exc) and exc.field
        return
    # accepted: the invariants the rest of mtcomp relies on
    names = m.axis_names
    assert len(set(names)) == len(names)
    sides = [a.side for a in m.axes]
    assert sides == sorted(sides, key=lambda s: s != "workpiece")  # workpiece side first
    for a in m.axes:
        assert a.resolution in RESOLUTIONS and 0 <= a.decimals <= 9
        assert abs(math.hypot(*a.direction) - 1) < 1e-12
        assert a.limits[0] < a.limits[1] and all(math.isfinite(x) for x in a.location)
        assert a.is_rotary == (a.name in "ABC")
    assert abs(math.hypot(*m.tool_axis) - 1) < 1e-12


@FUZZ
@given(st.sampled_from(PRESETS), st.integers(0, 9))
def test_machine_round_trip(tmp_path, name, k):
    m = load_machine(name)
    d = m.to_dict()
    d["axis"][0]["resolution"] = 10.0 ** -k
    f = tmp_path / "m.toml"
    f.write_text(dump_toml(d))
    back = load_machine(f)
    assert back.axes[0].decimals == k and back.axes[1:] == m.axes[1:]
    f.write_text(dump_toml(back.to_dict()))
    assert load_machine(f) == back
