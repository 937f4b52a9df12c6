"""Pilot tests of motion verbs in the TUI: the Eqns panel groups what a verb made under a heading
row with the verb's line, and its keys act on the whole group."""

from __future__ import annotations

import catalogue
import test_app_support as support
from test_app import run
from stw_tui.app import create_app
from stw_tui.app.panels import VERB_KEY

SCENE = catalogue.problem("analytic_arm3").text + """dof BX, BY
constraint hang: SHOULDER = -pi/2 @ 0
hold B at arm.tip on [0.2, 0.55]
ballistic B on [0.55, 1.5]
constraint goal: BX = 1.5, BY = 0.5 @ 1.5
objective effort: tau_SHOULDER, tau_ELBOW, tau_WRIST
"""


def rows(panel) -> list[tuple[str, list]]:
    return [(row.key.value, [str(cell) for cell in panel.get_row(row.key)]) for row in panel.ordered_rows]


async def focus_row(pilot, panel, key: str) -> None:
    panel.focus()
    panel.move_cursor(row=[k for k, _ in rows(panel)].index(key))
    await pilot.pause()


def test_the_equations_panel_groups_a_verbs_constraints_under_its_line(tmp_path):
    path = tmp_path / "verbs.stw"
    path.write_text(SCENE)
    app = create_app(path)

    async def scenario(pilot):
        await pilot.press("f2", "f2")                          # DOF, Eqns (a hidden tab is not redrawn)
        await support.settle(pilot)
        panel = app.query_one("#eqns-panel")
        shown = rows(panel)
        # Hand-written rows stay where they were written, each verb's parts come together under
        # a heading where its first constraint would have been, the objectives after.
        assert [k for k, _ in shown] == ["hang", VERB_KEY + "B_held", "B_caught", "B_released",
                                         VERB_KEY + "B_flight", "B_flight", "goal", "effort"]
        cells = dict(shown)
        assert [c[0] for _, c in shown] == ["hang", "B_held", "├ B_caught", "└ B_released",
                                         "B_flight", "└ B_flight", "goal", "effort"]
        # The heading: the verb's word, the time its parts cover (held on [0.2, 0.55], catch
        # @ 0.2, release @ 0.55), the worst violation of its constraints, and its line.
        violations = panel.info.violations
        worst = max(violations["B_caught"], violations["B_released"])
        # (The violation comes second, to be in view at 80x24.)
        assert cells[VERB_KEY + "B_held"] == ["B_held", f"{worst:.2e}", "on [0.2, 0.55]", "hold", "",
                                              "hold B at arm.tip on [0.2, 0.55]"]
        assert cells[VERB_KEY + "B_flight"][1:5] == [f"{violations['B_flight']:.2e}", "on [0.55, 1.5]",
                                                     "ballistic", ""]
        # Parts are rows like any other (weights, scopes, their own violations); so are the rest.
        assert cells["B_caught"][1:5] == [f"{violations['B_caught']:.2e}", "@ 0.2", "con", "1"]
        assert cells["hang"] == ["hang", f"{violations['hang']:.2e}", "@ 0", "con", "1", "SHOULDER = -pi/2 @ 0"]

        journalled = list(app.session.journal.replayable())
        await focus_row(pilot, panel, VERB_KEY + "B_held")
        await pilot.press("w")                                 # a verb has no weight of its own
        await support.settle(pilot)
        assert app.session.journal.replayable() == journalled
        await pilot.press("enter")                             # Enter: the verb's expansion
        await support.settle(pilot)
        assert "panel> show B_held" in support.log_text(app)
        assert "expands into 2 named constraint(s)" in support.log_text(app)

        await focus_row(pilot, panel, "B_caught")              # x on one part offers the group
        await pilot.press("x")
        await pilot.pause()
        assert app.screen._title.startswith("B_caught is part of verb B_held. Delete B_held and the 2 item(s)")
        assert app.screen.query_one("#dialog-input").value == "delete B_held"
        await pilot.press("enter")
        await support.settle(pilot)
        assert app.session.journal.replayable()[-1] == "delete B_held"
        assert [k for k, _ in rows(panel)] == ["hang", VERB_KEY + "B_flight", "B_flight", "goal", "effort"]
        await support.submit(pilot, "undo")                    # one step brings the whole group back
        await support.settle(pilot)
        assert [k for k, _ in rows(panel)][1:4] == [VERB_KEY + "B_held", "B_caught", "B_released"]

    run(scenario, app)
