"""A test-only procedure of many operator prompts and no devices, for the page's click tests.

Registered under ``prompts`` by the test that uses it (``procedures.registry.REGISTRY``
patched): ``N_PROMPTS`` prompt steps, each asking "Prompt k of N: ready?".
"""

from __future__ import annotations

from procedures.cell import prompt_step
from procedures.registry import ProcedureSpec, Subject
from procedures.session import Session
from station.runner import Procedure, Step

N_PROMPTS = 20


class NoCell:
    """The fake cell of a procedure without devices."""

    urls: dict = {}
    time_scale = 1.0

    def close(self) -> None:
        pass


def no_cell(params, fake) -> NoCell:
    return NoCell()


def build(params) -> Procedure:
    n = int(params["n"])
    return Procedure("prompts", [Step(f"prompt {k}", prompt_step(f"Prompt {k} of {n}: ready?"))
                                 for k in range(1, n + 1)])


SPEC = ProcedureSpec(
    name="prompts",
    new_params=lambda cfg, robot, report_dir, overrides: {"n": int(overrides.get("n", N_PROMPTS)),
                                                         "report_dir": report_dir},
    build=build,
    new_session=lambda devices: Session(devices),
    subject=lambda cfg, robot: Subject("test", "PROMPTS-1", None, "the prompt test"),
    device_roles=lambda cfg, robot: {},
    fake_cell="tests.web.prompts_procedure:no_cell",
    result_key="prompts",
    summary=lambda store, run_id: [],
)
