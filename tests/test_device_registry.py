"""Device kinds, backends and the simulator plug-in, found through the registry by name."""

from __future__ import annotations

import json
import typing
from pathlib import Path
from typing import Any

import msgspec
import pytest

from components.devices import KINDS, make_backend, make_device
from components.range.backend import RangeBackend
from components.range.ir import IR_MODELS
from components.sim.scenarios.scenario import load_scenario
from components.sim.world.config import WorldConfig
from components.sim.world.physics import World
from ubf_async.assembly import registry
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.devices import BACKEND_INJECTED, DEVICE_INJECTED, requires_simulator
from ubf_async.assembly.robotfile import load_robot_text
from ubf_async.assembly.simulation import OpenSimulation, SimulationOptions
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import (
    ConfigurationError,
    ParameterError,
    PluginError,
    RobotFileError,
    ScenarioError,
)
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component

EXPECTED_PARAMETERS = {
    "camera": {"latency_s", "hfov_deg", "view_scale", "seek_color", "x_m", "y_m", "z_m",
               "yaw_deg", "pitch_deg", "width_px", "height_px"},
    "motors": {"timeout_s", "left", "right"},
    "encoders": {"period_s", "direction", "effective_track_m", "origin_x_m", "origin_y_m",
                 "origin_heading_deg"},
    "range": {"model", "x_m", "y_m", "yaw_deg", "period_s"},
    "radio": {"period_s"},
    "leds": {"count", "period_s"},
}
EXPECTED_BACKENDS = {"camera": {"sim", "video"}, "motors": {"sim", "gpio"},
                     "encoders": {"sim", "gpio"}, "range": {"sim", "i2c", "ads1115"},
                     "radio": {"sim", "stdio", "air"}, "leds": {"sim", "gpio"}}
REQUIRED_BACKEND_PARAMS = {
    ("motors", "gpio"): {"left_pin": "GPIO12", "right_pin": "GPIO13"},
    ("encoders", "gpio"): {"left_a": "GPIO5", "left_b": "GPIO6", "right_a": "GPIO16",
                           "right_b": "GPIO26"},
    ("range", "ads1115"): {"sensor": "ir-10-80"},
    ("leds", "gpio"): {"pins": ["GPIO17", "GPIO27"]},
}
WRONG = [1, 2]
"""A value of the wrong type for every parameter: a list where a number, a string, a bool or
one of a few names is expected."""


def device_parameters(kind: str) -> type[msgspec.Struct]:
    return registry.parameters_of(registry.DEVICES.get(kind), injected=DEVICE_INJECTED)


def test_every_device_kind_loads_with_its_parameters() -> None:
    assert set(KINDS) <= set(registry.DEVICES.names())
    for kind in KINDS:
        assert callable(registry.DEVICES.get(kind))
        struct = device_parameters(kind)
        assert set(struct.__struct_fields__) == EXPECTED_PARAMETERS[kind], kind
        msgspec.convert({}, struct)  # every parameter has a default


def test_device_defaults_are_the_thesis_robot() -> None:
    assert msgspec.convert({}, device_parameters("camera")).latency_s == 0.11  # type: ignore[attr-defined]
    assert msgspec.convert({}, device_parameters("motors")).timeout_s == 0.11  # type: ignore[attr-defined]
    assert msgspec.convert({}, device_parameters("range")).model == "ir-10-80"  # type: ignore[attr-defined]


def test_range_models_are_the_ir_models() -> None:
    hints = typing.get_type_hints(registry.DEVICES.get("range"), include_extras=True)
    assert set(typing.get_args(hints["model"])) == set(IR_MODELS)


@pytest.mark.parametrize("kind", KINDS)
def test_device_parameters_refuse_a_wrong_type_naming_the_field(kind: str) -> None:
    struct = device_parameters(kind)
    for field in struct.__struct_fields__:
        with pytest.raises(msgspec.ValidationError, match=rf"\$\.{field}"):
            msgspec.convert({field: WRONG}, struct)


@pytest.mark.parametrize("kind", KINDS)
def test_device_parameters_refuse_an_unknown_parameter(kind: str) -> None:
    with pytest.raises(msgspec.ValidationError, match="unknown field `perod_s`"):
        msgspec.convert({"perod_s": 0.1}, device_parameters(kind))


def test_device_parameters_refuse_values_out_of_range() -> None:
    with pytest.raises(msgspec.ValidationError, match=r"\$\.period_s"):
        msgspec.convert({"period_s": 0}, device_parameters("encoders"))
    with pytest.raises(msgspec.ValidationError, match=r"\$\.direction"):
        msgspec.convert({"direction": "sideways"}, device_parameters("encoders"))
    with pytest.raises(msgspec.ValidationError, match=r"\$\.model"):
        msgspec.convert({"model": "ir-1-2"}, device_parameters("range"))
    with pytest.raises(msgspec.ValidationError, match=r"\$\.latency_s"):
        msgspec.convert({"latency_s": -0.1}, device_parameters("camera"))


def test_every_backend_loads_and_says_which_simulator_it_needs() -> None:
    for kind, names in EXPECTED_BACKENDS.items():
        assert set(registry.backends_for(kind)) == names, kind
        for name in names:
            factory = registry.get_backend(kind, name)
            assert hasattr(factory, "requires_simulator"), (kind, name)
            expected = ("mini-whegs" if (name == "sim" and kind not in ("radio", "leds"))
                        or (kind, name) == ("radio", "air") else None)
            assert requires_simulator(factory) == expected, (kind, name)
            struct = registry.parameters_of(factory, injected=BACKEND_INJECTED)
            required = REQUIRED_BACKEND_PARAMS.get((kind, name), {})
            for field in required:  # real hardware: where it is wired must be said
                with pytest.raises(msgspec.ValidationError, match=f"required field `{field}`"):
                    msgspec.convert({k: v for k, v in required.items() if k != field}, struct)
            msgspec.convert(required, struct)
            with pytest.raises(msgspec.ValidationError, match="unknown field"):
                msgspec.convert({**required, "bogus": 1}, struct)


def test_backend_parameters_are_checked() -> None:
    video = registry.parameters_of(registry.get_backend("camera", "video"),
                                   injected=BACKEND_INJECTED)
    assert msgspec.convert({}, video).source == "0"  # type: ignore[attr-defined]
    with pytest.raises(msgspec.ValidationError, match=r"\$\.width"):
        msgspec.convert({"width": 0}, video)
    encoders = registry.parameters_of(registry.get_backend("encoders", "sim"),
                                      injected=BACKEND_INJECTED)
    with pytest.raises(msgspec.ValidationError, match=r"\$\.glitch_probability"):
        msgspec.convert({"glitch_probability": 1.5}, encoders)


def test_camera_has_sim_and_video_backends() -> None:
    assert {"sim", "video"} <= set(registry.backends_for("camera"))


def test_an_unknown_backend_names_the_known_ones() -> None:
    with pytest.raises(PluginError, match=r"unknown backend 'camera\.nope'") as info:
        registry.get_backend("camera", "nope")
    assert "sim" in str(info.value) and "video" in str(info.value)
    assert "stdio" not in str(info.value)  # only the camera's


def test_the_simulator_is_a_plugin_like_any_other() -> None:
    assert "mini-whegs" in registry.SIMULATORS.names()
    simulator = registry.SIMULATORS.get("mini-whegs")()
    assert simulator.name == "mini-whegs"
    assert {"ball-in-sight", "ball-behind", "keep-away", "dance"} <= set(
        simulator.scenario_names())


@pytest.mark.asyncio
async def test_devices_build_through_the_registry_on_a_world(robot_bus: Bus) -> None:
    robot_bus.clock = SimClock()
    context = DeviceContext(bus=robot_bus, clock=robot_bus.clock, seed=5,
                            simulation=World(WorldConfig()))
    for kind in KINDS:
        backend = make_backend(kind, "sim", context=context)
        device = make_device(kind, context=context, backend=backend, name="x")
        assert isinstance(device, Component) and device.name == f"{kind}-x"
    encoders = make_device("encoders", context=context,
                           backend=make_backend("encoders", "sim", context=context),
                           params={"direction": "phase", "period_s": 0.01})
    assert encoders.period_s == 0.01  # type: ignore[attr-defined]
    with pytest.raises(ConfigurationError, match=r"range 'front'.*\$\.yaw_deg"):
        make_device("range", context=context, backend=None, params={"yaw_deg": "left"})
    with pytest.raises(ConfigurationError, match=r"backend encoders\.sim.*glitch"):
        make_backend("encoders", "sim", context=context, params={"glitch": 0.1})


class DuckRanger:
    """Reads like a range finder, but is no Backend: nothing says how it closes."""

    def distance_m(self, mount: object, *, max_range_m: float) -> float | None:
        return None


@pytest.mark.asyncio
async def test_a_backend_that_is_not_a_backend_is_refused_when_built(robot_bus: Bus) -> None:
    context = DeviceContext(bus=robot_bus, clock=robot_bus.clock)
    with pytest.raises(ConfigurationError, match=r"^range 'front': its backend is a "
                       r"DuckRanger, not a ubf_async\.assembly\.backend\.Backend"):
        make_device("range", context=context, backend=DuckRanger(), name="front")


@pytest.mark.asyncio
async def test_a_device_awaits_its_backends_aclose_once(robot_bus: Bus) -> None:
    closed: list[str] = []

    class Ranger(RangeBackend):
        def distance_m(self, mount: object, *, max_range_m: float) -> float | None:
            return None

        async def aclose(self) -> None:
            closed.append("aclose")  # not close(): the device awaits the one contract

    context = DeviceContext(bus=robot_bus, clock=robot_bus.clock)
    device = make_device("range", context=context, backend=Ranger(), name="front")
    await device.aclose()
    await device.aclose()
    assert closed == ["aclose"]


# The same bad parameter, given in a robot file and to a device started on its own (the
# parameters are checked before anything is built: no bus is needed): the device kind, its
# params, its backend's, and where in the robot file the mistake is.
SAME_MISTAKES = [
    ("range", {"yaw_deg": "left"}, {}, "params.yaw_deg"),
    ("range", {"model": "GP2Y9999"}, {}, "params.model"),
    ("range", {"yaw": 10}, {}, "params"),
    ("range", {}, {"noise": 1}, "backend_params"),
    ("encoders", {}, {"glitch": 0.1}, "backend_params"),
    ("encoders", {}, {"glitch_probability": 1.5}, "backend_params.glitch_probability"),
]


@pytest.mark.parametrize(("kind", "params", "backend_params", "place"), SAME_MISTAKES)
def test_a_robot_file_and_a_device_on_its_own_refuse_a_parameter_alike(
        kind: str, params: dict[str, Any], backend_params: dict[str, Any], place: str) -> None:
    context = DeviceContext(bus=None, clock=SimClock())  # type: ignore[arg-type]
    with pytest.raises(ParameterError) as alone:
        if params:
            make_device(kind, context=context, backend=None, name="front", params=params)
        else:
            make_backend(kind, "sim", context=context, params=backend_params)
    text = ("name: tester\n"
            "tree: {name: root, arbiter: HighestPriority, children: [{behavior: stop}]}\n"
            "devices:\n"
            f"  - kind: {kind}\n"
            "    name: front\n"
            "    backend: sim\n"
            f"    params: {json.dumps(params)}\n"
            f"    backend_params: {json.dumps(backend_params)}\n")
    with pytest.raises(RobotFileError) as in_file:
        load_robot_text(text, source="robot.yaml")
    refusal = alone.value
    line = 7 if place.startswith("params") else 8
    assert str(in_file.value) == f"robot.yaml:{line}: {refusal.told_at(f'devices[0].{place}')}"
    # One refusal: the device or its backend named alike, the mistake, what it does take.
    assert refusal.what == (f"{kind} 'front'" if params else f"backend {kind}.sim")
    assert next(iter({**params, **backend_params})) in str(refusal)
    assert str(refusal).endswith(f"; it takes: {', '.join(refusal.takes) or 'none'}")


@pytest.mark.asyncio
async def test_a_simulated_backend_without_a_simulator_says_so(robot_bus: Bus) -> None:
    context = DeviceContext(bus=robot_bus, clock=robot_bus.clock)
    with pytest.raises(ConfigurationError, match="needs the 'mini-whegs' simulator"):
        make_backend("range", "sim", context=context)


@pytest.mark.asyncio
async def test_the_video_backend_reports_a_source_it_cannot_open(robot_bus: Bus,
                                                                 tmp_path: Path) -> None:
    context = DeviceContext(bus=robot_bus, clock=robot_bus.clock)
    with pytest.raises(ConfigurationError, match="cannot open video file"):
        make_backend("camera", "video", context=context,
                     params={"source": str(tmp_path / "missing.avi")})


@pytest.mark.asyncio
@pytest.mark.parametrize("options, error, message", [
    (SimulationOptions(scenario="no-such-scenario"), ScenarioError, "unknown scenario"),
    (SimulationOptions(speed=0.0), ConfigurationError, "speed must be"),
    (SimulationOptions(speed=-2.0), ConfigurationError, "speed must be"),
    (SimulationOptions(duration_s=0.0), ConfigurationError, "duration must be"),
])
async def test_opening_a_run_with_bad_options_raises(
    robot_bus: Bus, options: SimulationOptions, error: type[Exception], message: str
) -> None:
    simulator = registry.SIMULATORS.get("mini-whegs")()
    with pytest.raises(error, match=message):
        simulator.open(bus=robot_bus, clock=SimClock(), options=options)


@pytest.mark.asyncio
async def test_an_opened_run_follows_the_seam(robot_bus: Bus) -> None:
    simulator = registry.SIMULATORS.get("mini-whegs")()
    run = simulator.open(bus=robot_bus, clock=SimClock(),
                         options=SimulationOptions(scenario="dance", seed=9))
    assert isinstance(run, OpenSimulation)
    assert run.seed == 9
    assert run.duration_s == load_scenario("dance").duration_s
    assert isinstance(run.world, World)
    assert [c.name for c in run.components()] == ["sim"]
    assert not hasattr(run, "search_period_s")
    default = simulator.open(bus=robot_bus, clock=SimClock(), options=SimulationOptions())
    assert default.duration_s is None  # no scenario named: until stopped


def old_scenario(tmp_path: Path, **extra: Any) -> Path:
    path = tmp_path / "old.json"
    path.write_text(json.dumps({"name": "old", "duration_s": 5, **extra}))
    return path


def test_a_scenario_with_search_period_loads_with_a_deprecation_warning(tmp_path: Path) -> None:
    with pytest.warns(DeprecationWarning, match="period_s of the search behaviour in the robot"):
        scenario = load_scenario(str(old_scenario(tmp_path, search_period_s=4)))
    assert scenario.duration_s == 5
    assert not hasattr(scenario, "search_period_s")
    with pytest.raises(ScenarioError, match="search_period_s"):
        load_scenario(str(old_scenario(tmp_path, search_period_s="soon")))


def test_shipped_scenarios_load_without_warnings() -> None:
    simulator = registry.SIMULATORS.get("mini-whegs")()
    for name in simulator.scenario_names():  # filterwarnings = error: a warning fails here
        load_scenario(name)


def test_scenario_error_is_the_framework_one() -> None:
    from components.sim.scenarios import scenario as scenarios

    assert scenarios.ScenarioError is ScenarioError
