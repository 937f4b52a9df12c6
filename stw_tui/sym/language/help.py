"""Help text for every command of the session language (`help`, `help COMMAND`)."""

from __future__ import annotations

import difflib
from dataclasses import dataclass

from stw_tui.sym import limits
from stw_tui.sym.errors import StwError
from stw_tui.sym.language.expressions import FUNCTIONS


@dataclass(frozen=True)
class CommandHelp:
    """One command's help: its synopsis, what it does, and an example."""

    synopsis: str
    summary: str
    example: str
    picture: str = ""   # a small drawing in text, after the example


# what `save` and `export` write, and where
_WRITES = ("An existing FILE is replaced only with `overwrite`, and never a link or anything but a "
           "regular file; a session file's line writes only inside the file's own folder. ")

COMMAND_HELP: dict[str, CommandHelp] = {
    "time": CommandHelp("time START END [knots=N] [samples=K]",
                        "Set the animation span, the default knot spans of new DOF, and K, the constraint "
                        "instances per animation span for `on [A, B]` constraints (default 2*knots).",
                        "time 0 1.5 knots=24 samples=48"),
    "const": CommandHelp("const NAME = VALUE[, NAME = VALUE…]",
                         "Declare constants, or change their values. Constants are runtime parameters: "
                         "changing one never recompiles.", "const m = 1, g = 9.81"),
    "dof": CommandHelp("dof NAME[, NAME…] [= EXPR] [knots=N] [lo=A] [hi=B]",
                       "Declare DOF as cubic B-spline curves (constant 0, or fitted to EXPR of t and "
                       "constants). On an existing DOF, `= EXPR` refits the curve and knots=N re-knots it; "
                       "lo/hi bound its values: they bound its control points, so the curve holds them everywhere.",
                       "dof x, y = 0.5*t^2 knots=10 lo=0"),
    "let": CommandHelp("let NAME = EXPR",
                       "Define a subexpression, substituted wherever it is named.", "let f = m*x'' + m*g"),
    "constraint": CommandHelp("constraint NAME: REL[, REL…] (@ T | on [A, B]) [when COND] [weight=W] "
                              "[samples=K] [dense_tol=D]",
                              "A constraint: REL is E = E, E >= E or E <= E; at an instant or at sample "
                              "instances over an interval (K per animation span; default the time's "
                              "samples; a relation linear in DOF, like BY'' + g = 0, gets instances that "
                              "make it hold exactly); optionally only where COND holds (comparisons with "
                              "and/or/not). After a solve it is checked between its instances too, "
                              "against D (default: `set dense_tol`). f' and f'' of a subexpression f are "
                              "its time derivatives (arm.tip.x' is the hand's velocity).",
                              "constraint floor: y >= 0 on [0, 1.5] when x > 1"),
    "objective": CommandHelp("objective NAME: [maximize|minimize] EXPR[, EXPR…] [on [A, B] | @ T] [weight=W]",
                             "Minimize the weighted integral of each expression squared (over the span, "
                             "or on [A, B]); with @ T, a terminal cost: W times each expression squared "
                             "at the instant T (EXPR - 2 @ 1: end as near 2 as it can). Each enters the "
                             "merit as its weighted square. `maximize EXPR` (one expression) enters as "
                             "-W times its value (its integral, or its value at T), `minimize EXPR` as "
                             "+W times it: signed, not squared, so give the motion something that bounds "
                             "it (an effort objective, constraints, DOF bounds), or the solve runs away. "
                             "Only the scipy SQP and ipopt backends take them.",
                             "objective high: maximize BY @ 1 weight=10"),
    "key": CommandHelp("key T DOF=V[, DOF=V…]",
                       "Sketch a keyframe: bend the DOF curves smoothly through V at time T (starting "
                       "values for the optimizer, not constraints).", "key 0.75 SHOULDER=2.5 ELBOW=0.5"),
    "window": CommandHelp("window NAME [dofs=a,b|all] [[A, B]]",
                          "Define a spacetime window (a subset of DOF over a time interval) and use it: "
                          "iterations change only its control points.",
                          "window release dofs=BX,BY [0.4, 0.8]"),
    "hold": CommandHelp("hold P at POINT on [A, B] [mass=M]",
                        "The object P (DOF PX, PY[, PZ]) is the linkage point (arm.tip) while held: "
                        "every expression reads PX as arm.tip.x (and PX' as arm.tip.x', ...) on [A, B], "
                        "so it is in the hand at every time. Its own curve, used outside the hold, meets "
                        "the point's position and velocity at A (P_caught, unless A is the start) and at B "
                        "(P_released, unless B is the end). mass=M (kg) adds the held mass at the point to "
                        "the linkage's generalized forces (tau_J) while held. `delete P_held` removes all "
                        "of it.",
                        "hold B at arm.tip on [0, 0.55] mass=0.2"),
    "ballistic": CommandHelp("ballistic P on [A, B]",
                             "Free flight of the object P under g (along -y): constraint P_flight, "
                             "PX'' = 0, PY'' + g = 0 (PZ'' = 0), exact between the samples. "
                             "`delete P_flight` removes it.",
                             "ballistic B on [0.55, 1.5]"),
    "contact": CommandHelp("contact POINT on ground [y=H] on [A, B] x=X0 [friction=MU] [support=[L, R]] [dense_tol=D] "
                           "[force=F] [angle=PHI]",
                           "The linkage point (its first joint) is planted at (X0, H) by construction: over "
                           "the stance the creature hangs from it (its centre of mass, com=, is read as the "
                           "point plus the links' offset), so it cannot slide, sink or move; the flight's "
                           "own curves meet it at rest at the touchdown and the lift-off (POINT_touchdown, "
                           "POINT_liftoff). The ground only pushes (POINT_push: the base's y force >= 0), "
                           "within the friction cone (POINT_friction, MU = 1 by default), with its centre "
                           "of pressure on the support [L, R] along the ground (POINT_pressure; a point "
                           "foot [0, 0] by default). These hold at their instances and between them to 1% "
                           "of the creature's weight (N; weight x size for the moment), or to dense_tol=D. "
                           "A second foot at the end of a branch (fig.RFOOT.end, planar revolute links) "
                           "takes force=F: the ground's force on it is DOF FX, FY (and FM, its moment "
                           "about the point, with a sole), which you declare first and which load every "
                           "tau_J; over the stance the leg's joints are what plants it (two-link inverse "
                           "kinematics from the hip, the knee bent as at the touchdown, kept 0.05 rad from "
                           "straight: POINT_reach), its sole keeping angle=PHI (default: as at the touchdown), e.g. "
                           "`dof RX, RY, RM` then `contact fig.RFOOT.end on ground on [0, 0.6] x=0.3 "
                           "support=[-0.2, 0] force=R`. "
                           "`delete POINT_contact` (FOOT_contact) removes all of it.",
                           "contact acro.FOOT on ground on [0, 0.5] friction=1 x=0"),
    "flight": CommandHelp("flight LINKAGE on [A, B] [dense_tol=D]",
                          "Nothing outside acts on the creature: the forces of its base DOF and the "
                          "torques of the joints up to its first massive link (which hang on the "
                          "base: a base with base_inertia= takes them) are 0 (LINKAGE_flight, LINKAGE_spin). With `com=CX,CY` the base part is "
                          "linear (CX'' = 0, CY'' + g = 0) and holds everywhere; the torques are "
                          "nonlinear, and dense_tol=D states how large they may grow between the "
                          "instances. "
                          "`delete LINKAGE_flight` removes it.",
                          "flight acro on [0.5, 1]"),
    "avoid": CommandHelp("avoid LINK (LINK | ground [y=H]) [by=D] [on [A, B]] [dense_tol=E]",
                         "Keeps two links at least D apart (D = 0.01 m unless by= says), over the "
                         "whole animation or on [A, B]: a link is named by its joint (fig.LARM: from "
                         "the LARM joint to where its link ends). Two links joined at a joint (an "
                         "elbow, two arms on a shoulder) keep their angle at least asin(D / shorter "
                         "link) from the fold, so one cannot fold through the other; two others keep "
                         "each end D from the other link; against `ground`, both ends stay D above "
                         "y = H (0 unless y= says). These hold at the instances and, by the "
                         "continuous-time check, between them to dense_tol=E (1 mm, or 1e-3 rad for "
                         "an angle, unless given). "
                         "`delete LARM_TRUNK_avoid` removes it.",
                         "avoid fig.LARM fig.TRUNK by=0.05"),
    "limit": CommandHelp("limit DOF A B",
                         "A range for a DOF (a joint's limits): A <= DOF <= B everywhere, imposed on its "
                         "control points. The same as `dof DOF lo=A hi=B` (no group: a range is the DOF's own). "
                         "A negative B goes in parentheses (`limit KNEE -2.9 (-0.9)`): `-2.9 -0.9` "
                         "would read as one number, -3.8.",
                         "limit ELBOW 0 2.5"),
    "slide": CommandHelp("slide WINDOW by DT [to T] [iterate N]",
                         "Move a window along the time axis by DT at a time, solving N iterations "
                         "(default 10) at each position, from where it is until its end reaches T "
                         "(default: the end of the animation). Each solve sees only its window.",
                         "slide chase by 0.25 iterate 10"),
    "use": CommandHelp("use NAME", "Iterate on a defined window (`use all` for everything).", "use all"),
    "weight": CommandHelp("weight NAME W", "Set the weight of a constraint or objective.", "weight goal 10"),
    "damp": CommandHelp("damp DOF D",
                        "Damp the change of a DOF's control points per iteration (adds D·|ΔS|² to each "
                        "step's model).", "damp WRIST 0.2"),
    "filter": CommandHelp("filter DOF [PASSES]", "Smooth a DOF curve's control points (1-2-1 filter).",
                          "filter x 2"),
    "shake": CommandHelp("shake [DOF…] amplitude=A [seed=S]",
                         "Perturb control points with seeded random noise (default: the window's DOF; "
                         "in a window with an interval, only the control points it frees) to leave a "
                         "local minimum.", "shake x y amplitude=0.05 seed=3"),
    "refine": CommandHelp("refine DOF [[A, B]] | refine DOF @ T [multiplicity=M]",
                          "Insert knots halving every span of the DOF over [A, B] (default: the window), "
                          "or a knot at T, M times in all (2: the DOF's acceleration may jump there, "
                          "as a foot's does at take-off; 3: its velocity too); the curve is unchanged.",
                          "refine BX [0.4, 0.8]"),
    "backend": CommandHelp("backend NAME [OPTION=VALUE…]",
                           "Choose the solver backend and its options (`stw backends` lists them).",
                           "backend scipy solver=minres"),
    "set": CommandHelp("set OPTION VALUE",
                       "Settings: tol_violation, tol_kkt, tol_step, quadrature (points per span), merit "
                       "(least violation weight), frame (player time), samples, dense_tol (largest "
                       "violation allowed between instances), adaptive on|off (where the continuous-time "
                       "check fails, refine the curves there and add instances, and re-solve), "
                       "adaptive_rounds (re-solves per `iterate`), adaptive_points (the scene's "
                       "control points that refinement may reach; default 2000). "
                       "`set limit NAME N` changes a limit (`help limits` lists them); "
                       "`set scheduler tcp://HOST:PORT` sends surveys to a Dask cluster, when typed here "
                       "(a session file or journal may name only a cluster you name: STW_SCHEDULER or "
                       "`stw survey --scheduler`; tls:// uses Dask's TLS config) (`set scheduler batch`: "
                       "solves their starts as one batch on the torch backend).",
                       "set dense_tol 1e-7"),
    "iterate": CommandHelp("iterate [N] [adapt=R]",
                           "Run up to N SQP iterations on the current window (stops early on convergence). "
                           "Then every constraint is checked densely over the whole animation; with "
                           "`set adaptive on` (the default) the curves are refined (knots inserted in the DOF "
                           "the failing constraint reads) and instances added where it fails, and the "
                           "window re-solved from where it ended, at most R times (default: "
                           "adaptive_rounds) and up to adaptive_points control points.",
                           "iterate 20"),
    "instances": CommandHelp("instances NAME add T[, T…] | instances NAME clear",
                             "Add constraint instances at times T (NAME is a constraint, or DOF.bounds "
                             "for a DOF's lo/hi), or drop the added ones. Adaptive refinement adds "
                             "them for you where the continuous-time check fails.",
                             "instances in_hand add 0.52, 0.56"),
    "delete": CommandHelp("delete NAME",
                          "Delete a constraint, objective, subexpression, window, constant or DOF (refused "
                          "while something else uses it). A motion verb's group (B_held, B_flight, "
                          "FOOT_contact, acro_flight: the Eqns panel's headings) goes whole, in one "
                          "undoable step; one part of a verb is not deleted alone (the verb would no "
                          "longer do what its line says): delete the group, or reweigh the part.",
                          "delete B_held"),
    "print": CommandHelp("print EXPR [@ T | on [A, B]] | print CONSTRAINT",
                         "Print an expression's value at T, or a summary (min, max, mean, ends) over [A, B] "
                         "(default: the span); or how well a constraint holds: its violation at its "
                         "instances, densely over its whole scope, and where it is worst.",
                         "print x'' @ 0.5"),
    "help": CommandHelp("help [COMMAND]", "List the commands, or document one.", "help constraint"),
    "linkage": CommandHelp("linkage NAME [base=fixed|AXIS:DOF,…] [com=CX,CY] [gravity=-y] "
                           "[base_mass=M] [base_inertia=I] … end",
                           "A block: one row per joint (`JOINT revolute|prismatic a= alpha= d= theta= "
                           "mass= com=x:y:z inertia=Ixx:Iyy:Izz`), closed by `end`. Joint variables "
                           "become DOF; positions (NAME.JOINT.x, NAME.tip.y, NAME.com.z) and generalized "
                           "forces tau_DOF become subexpressions. Planar conventions: y is up (gravity=-y, "
                           "of magnitude the constant g), a revolute joint's angle is measured "
                           "counterclockwise, the first from +x, each next one from the link before "
                           "(0 = straight on). Rows form a chain, each hanging from the end of the link "
                           "above; `parent=P` hangs a row from the end of P's link instead (`parent=base`: "
                           "from the base), so a linkage may branch into a tree (two legs, two arms, a "
                           "head), and each link's end is then NAME.JOINT.end.x. A link is by default a uniform rod of length a (mass 1): "
                           "its mass mid-link, inertia m a^2/12 about its middle. The base axes "
                           "(tx, ty, tz, rx, ry, rz) apply in the order given; `base_mass=M` puts a mass "
                           "at the base frame origin after them (it counts in NAME.com and in the base "
                           "forces: a cart), `base_inertia=I` a moment of inertia about the base's one "
                           "rotation (tau_R gains I*R''). With a base of translations, "
                           "`com=CX,CY` makes the DOF the centre of mass (base_mass included) and the base "
                           "a subexpression (free flight is then CX'' = 0, CY'' + g = 0, exact between "
                           "the samples).",
                           "linkage cp base=tx:X base_mass=1\n  POLE revolute a=0.5 mass=0.2\nend\n"
                           "linkage fig base=tx:X,ty:Y\n  SHIN revolute a=0.45 mass=3.5\n"
                           "  TRUNK revolute a=0.6 mass=30 parent=base\n  ARM revolute a=0.6 mass=3\n"
                           "  HEAD revolute a=0.25 mass=5 parent=TRUNK\nend",
                           # `linkage arm` with SHOULDER a=0.6 and ELBOW a=0.5, at SHOULDER = 0, ELBOW = pi/2
                           "  y                               o arm.tip (arm.tip.x, arm.tip.y)\n"
                           "  ^                               |\n"
                           "  |                       forearm | a=0.5: its mass mid-link,\n"
                           "  |                               |  inertia m a^2/12 (defaults)\n"
                           "  |   SHOULDER = 0: from +x       |\n"
                           "  |                               |  ELBOW = pi/2: counterclockwise\n"
                           "  |           upper arm a=0.6     |  from the upper arm's line\n"
                           "  o-------------------------------o - - - - (ELBOW = 0: straight on)\n"
                           "  base: arm.SHOULDER              arm.ELBOW       gravity -y, x to the right"),
}

OPERATORS = "+ - * / ^ (or **), unary -, parentheses; x' and x'' are a DOF's velocity and acceleration; t is time"


def help_text(topic: str | None = None) -> str:
    """All commands with one-line summaries, or one command in full.

    Raises:
        StwError: unknown topic (with close matches).
    """
    if topic is None:
        width = max(len(name) for name in COMMAND_HELP)
        lines = ["Commands (help COMMAND for details):"]
        lines += [f"  {name:<{width}}  {h.summary.split('. ')[0].rstrip('.')}" for name, h in COMMAND_HELP.items()]
        lines.append("Functions: " + ", ".join(FUNCTIONS) + "; constant pi")
        lines.append("Operators: " + OPERATORS)
        lines.append("Limits: `help limits` lists what one line may ask for")
        return "\n".join(lines)
    if topic == "limits":
        return limits.help_text()
    if topic not in COMMAND_HELP:
        close = difflib.get_close_matches(topic, list(COMMAND_HELP), n=2)
        hint = f" (did you mean {' or '.join(close)}?)" if close else ""
        raise StwError(f"no help for '{topic}'{hint}")
    h = COMMAND_HELP[topic]
    text = f"{h.synopsis}\n  {h.summary}\n  example: {h.example}"
    return text + (f"\n  picture:\n{h.picture}" if h.picture else "")


# Commands on the session rather than the scene (language/session_commands.py).
COMMAND_HELP.update({
    "undo": CommandHelp("undo",
                        "Take back the last command that changed the scene (a solve included), exactly: "
                        "control points, constants, constraints, windows, weights and settings return "
                        "bit for bit. `print`, `show`, `cse`, `help`, `snapshot`, `snapshots`, `diff`, "
                        "`export` and `save` change nothing and are not undone.", "undo"),
    "redo": CommandHelp("redo", "Do again what `undo` took back (until another command changes the scene).",
                        "redo"),
    "snapshot": CommandHelp("snapshot NAME",
                            "Keep the scene as it is now under NAME (replacing a snapshot of that name), "
                            "to `restore` or `diff` later.", "snapshot before_release"),
    "restore": CommandHelp("restore NAME",
                           "Make the scene what it was at `snapshot NAME` (one step: `undo` takes it back).",
                           "restore before_release"),
    "snapshots": CommandHelp("snapshots",
                             "List the snapshots with each one's objective and largest constraint violation "
                             "(at the instances, and densely between them).", "snapshots"),
    "diff": CommandHelp("diff NAME",
                        "Compare the scene with snapshot NAME: which DOF changed and by how much (the "
                        "largest difference of the curve over the animation), other definitions that "
                        "changed, and the objective and violation before and after.",
                        "diff before_release"),
    "export": CommandHelp("export csv|json|bvh FILE [fps=N] [what=NAME,…] [overwrite]",
                          "Write the motion sampled at N frames per second (default 30): per frame the "
                          "time, every DOF with its first and second derivatives, and every linkage "
                          "joint, tip and centre of mass position, and each subexpression NAME (a let, "
                          "tau_JOINT, arm.tip.x'); json adds the control points, knots "
                          "and the session text; bvh writes a linkage's skeleton (from its DH rows) "
                          "and per frame its base translation and joint angles in degrees, for "
                          "Blender (what=LINKAGE chooses one). Quote a path with spaces. " + _WRITES + "The scene does "
                          "not change.",
                          "export csv throw.csv fps=60"),
    "show": CommandHelp("show NAME | show EXPR [@ T] | show diff(EXPR, VAR) [@ T]",
                        "What a name is, as the compiler sees it: a constraint's relations as written, "
                        "with every subexpression substituted (as compiled) and simplified when small, "
                        "with its scope, instance count and weight; an objective's terms; a DOF's knots, "
                        "control points and bounds; a subexpression's definition; a motion verb's line "
                        "and the constraints it expands into. `show EXPR` prints any expression "
                        "expanded and simplified (`@ T` adds its value); diff(EXPR, VAR) its partial "
                        "derivative by VAR (x, x', x'', t or a constant). The scene does not change.",
                        "show diff(f, ELBOW'')"),
    "cse": CommandHelp("cse NAME | cse EXPR",
                       "The common subexpressions (x0, x1, …) the compiler shares when it compiles a "
                       "constraint's relations, an objective's terms, a subexpression or an expression, "
                       "and each term written with them.", "cse tau_ELBOW"),
    "journal": CommandHelp("journal",
                           "Where this session is journalled (every command, fsynced before it is "
                           "acknowledged), its checkpoints, and the directory of autosaved sessions; "
                           "`stw --resume [JOURNAL]` reopens one without solving again.", "journal"),
    "accept": CommandHelp("accept",
                          "With `set preview on`, a solve leaves the scene as it was and proposes its "
                          "result, with the objective and violation of both; `accept` makes the "
                          "proposal the scene (a step: `undo` takes it back; F9 in the TUI, F10 "
                          "rejects). A command that changes the scene drops the proposal.", "accept"),
    "reject": CommandHelp("reject", "Drop the proposal of the last solve under `set preview on`; the scene "
                          "stays as it was.", "reject"),
    "open": CommandHelp("open FILE",
                        "Run a session file's lines as if typed: each is journalled and undoable on its "
                        "own (a replay never reads FILE again). Stops at the first line that fails; a "
                        "file whose first line is not a command is refused unread.",
                        "open throw.stw"),
    "save": CommandHelp("save FILE [--journal] [overwrite]",
                        "Write the session so far as a clean, replayable .stw file: the lines that made "
                        "the scene, in order (no failed lines, no undone lines nor the `undo`, no `print` "
                        "or other queries; a `restore` or `accept` as the lines that made that state). "
                        "`--journal` writes everything as the journal has it, failed lines as comments. "
                        + _WRITES + "The scene does not change.", "save throw.stw"),
    "survey": CommandHelp("survey N [seed=S] [from=shake|sketch|random] [amplitude=A] [window=W] [workers=K] "
                          "[iterate=M]",
                          "Solve N starts made from the scene (shaken curves, the default; jittered keyframes; "
                          "or random curves, each with amplitude A, default 0.5) with up to M iterations each "
                          "(default 100) in window W (default the one in use; with an interval, shaken starts only), and list the distinct local "
                          "optima they reach, best first, with how many starts reached each; starts that fail "
                          "or do not converge are counted apart. The same seed gives the same survey. Starts "
                          "run on Dask (K worker processes, default one per core), or on a local process pool "
                          "without it; `set scheduler tcp://HOST:PORT` (typed) sends them to an existing Dask cluster "
                          "(`set scheduler local`: back to this machine; `pool`: a process pool even with Dask; "
                          "`serial`: one start after another in this process; `batch`: all starts as one batch on the "
                          "torch backend, vectorized over starts, on a GPU when torch sees one, K starts at "
                          "a time, default 64). The scene does not change.",
                          "survey 40 seed=1 amplitude=0.8 window=all"),
    "adopt": CommandHelp("adopt K",
                         "Make optimum K of the last survey the scene: its start is applied and solved again "
                         "(the journal keeps those lines; `undo` takes it back).", "adopt 2"),
})
