"""Setting a device parameter in a robot file's text (``ubf_async.assembly.robotedit``, what
colour calibration writes with): in each layout a file may have, only that value's text
changes — comments, order and the other values stay byte for byte — and a layout the edit
cannot follow is refused at its line with what to write by hand."""

from __future__ import annotations

import pytest

from ubf_async.assembly.robotedit import flow_yaml, set_device_param
from ubf_async.errors import RobotFileError

HEAD = "format: 1\nname: r\ndevices:\n"
TREE = "tree:\n  name: root\n  arbiter: PriorityMerge\n  children:\n    - behavior: search\n"
CAMERA = "  - kind: camera  # the front one\n    name: front\n    backend: sim\n"
VALUE = {"lo": [100, 30, 60], "hi": [255, 200, 230]}
WRITTEN = flow_yaml(VALUE)


def edited(devices: str) -> str:
    text = HEAD + devices + TREE
    return set_device_param(text, kind="camera", name="front", key="seek_color", value=VALUE,
                            source="r.yaml").removeprefix(HEAD).removesuffix(TREE)


@pytest.mark.parametrize(("devices", "expected"), [
    (CAMERA + "    params: {latency_s: 0.1}  # its latency\n",
     CAMERA + f"    params: {{latency_s: 0.1, seek_color: {WRITTEN}}}  # its latency\n"),
    (CAMERA + "    params: {}\n", CAMERA + f"    params: {{seek_color: {WRITTEN}}}\n"),
    (CAMERA + "    params:\n      latency_s: 0.1   # its latency\n\n  # the LEDs\n"
              "  - kind: leds\n    name: panel\n    backend: sim\n",
     CAMERA + f"    params:\n      latency_s: 0.1   # its latency\n      seek_color: {WRITTEN}"
              f"\n\n  # the LEDs\n  - kind: leds\n    name: panel\n    backend: sim\n"),
    (CAMERA, CAMERA + f"    params: {{seek_color: {WRITTEN}}}\n"),
    (CAMERA + "    params: {seek_color: {lo: [1, 2, 3], hi: [4, 5, 6]}, latency_s: 0}\n",
     CAMERA + f"    params: {{seek_color: {WRITTEN}, latency_s: 0}}\n"),
    (CAMERA + "    params:\n      seek_color:  # mine\n        lo: [1, 2, 3]  # dark\n"
              "        hi:\n          - 4\n          - 5  # green\n          - 6\n",
     CAMERA + "    params:\n      seek_color:  # mine\n        lo: [100, 30, 60]  # dark\n"
              "        hi:\n          - 255\n          - 200  # green\n          - 230\n"),
], ids=["flow params", "empty flow params", "block params", "no params",
        "replaced in flow", "replaced in block, entry by entry"])
def test_only_the_value_changes(devices: str, expected: str) -> None:
    assert edited(devices) == expected


@pytest.mark.parametrize(("devices", "said"), [
    (CAMERA + "    params:\n      seek_color:\n        lo: [1, 2, 3]\n        hi: [4, 5, 6]\n"
              "        require_r_gt_b_gt_g: false\n",
     "r.yaml:8: cannot set devices[0].params.seek_color in the file's text (it also sets "
     "require_r_gt_b_gt_g): write seek_color: {lo: [100, 30, 60], hi: [255, 200, 230]} there "
     "by hand"),
    (CAMERA + "    params: &shared {latency_s: 0.1}\n  - kind: camera\n    name: back\n"
              "    backend: sim\n    params: *shared\n",
     "r.yaml:7: cannot set devices[0].params.seek_color in the file's text (the edit would "
     "change more than that value)"),
    ("  - kind: range\n    name: front\n    backend: sim\n",
     "r.yaml: no device camera/front in its devices"),
], ids=["a key the value does not set", "params shared through an alias", "no such device"])
def test_a_layout_the_edit_cannot_follow_is_refused(devices: str, said: str) -> None:
    with pytest.raises(RobotFileError) as refused:
        edited(devices)
    assert str(refused.value).startswith(said), refused.value


def test_a_value_the_robot_file_refuses_is_not_written() -> None:
    with pytest.raises(RobotFileError, match=r"r\.yaml:7: .*exceeds hi"):
        set_device_param(HEAD + CAMERA + TREE, kind="camera", name="front", key="seek_color",
                         value={"lo": [200, 0, 0], "hi": [100, 0, 0]}, source="r.yaml")
