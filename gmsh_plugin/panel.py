"""The ONELAB panel "hexsos" in the Gmsh GUI: parameters, Check and Repair buttons, read-only results.

A Python script cannot add an entry under Gmsh's Tools > Plugins; Gmsh's convention (its
``examples/api/custom_gui.py``, ``prepro.py``, ``tutorials/python/t13.py``) is a script that embeds the Gmsh
GUI and defines ONELAB parameters. A button is a string parameter with the attribute ``"Macro": "Action"``:
clicking it sets ``ONELAB/Action`` to the parameter's value, and the script's event loop reacts::

    gmsh.fltk.initialize()
    while gmsh.fltk.isAvailable() and handle_action():
        gmsh.fltk.wait()

:func:`handle_action` needs no display: tests (and scripts) set ``ONELAB/Action`` to :data:`ACTION_CHECK` or
:data:`ACTION_REPAIR`, exactly as the buttons do, call it, and read the results back from ONELAB.

The panel (names as stored in ONELAB; Gmsh hides the leading digits, which fix the order)::

    hexsos
      Parameters   Method (auto | sos), Relaxation (quad2 | paper), Repair method (optimize | paper), Repair
                   boundary (slide | fixed | free), Target min scaled J (auto | number), Pin boundary, Repair
                   iterations, Fix orientation; the paper's method's own last: Rho, Margin (auto | number)
      [Check]  [Repair]
      Results      Elements checked, Invalid, Invalid inside only, Undecided, Minimum det J, Not checked,
                   Message (with the counts per element type), Minimum scaled J, Others not valid (3-D
                   elements other than 8-node hexahedra)
"""

from __future__ import annotations

import json
import math
import time

import numpy as np

from hexsos_plugins.errors import HexsosError, InvalidInputError
from hexsos_plugins.meshrepair import step_words

from gmsh_plugin.model import gmsh_api, check_model, repair_model

__all__ = [
    "ACTION_CHECK",
    "ACTION_REPAIR",
    "ACTIONS",
    "P_METHOD",
    "P_RELAXATION",
    "P_RHO",
    "P_MARGIN",
    "P_PIN",
    "P_MAX_ITER",
    "P_FIX",
    "P_REPAIR_METHOD",
    "P_BOUNDARY",
    "P_MIN_SJ",
    "P_CHECK",
    "P_REPAIR",
    "R_HEXES",
    "R_INVALID",
    "R_INSIDE_ONLY",
    "R_UNDECIDED",
    "R_MIN_DET",
    "R_SKIPPED",
    "R_MESSAGE",
    "R_MIN_SJ",
    "R_OTHER",
    "define_parameters",
    "read_parameters",
    "handle_action",
    "run_check",
    "run_repair",
    "gui_available",
    "last_result",
    "last_error",
    "event_loop",
    "widen_menu",
]

#: Values the buttons set ``ONELAB/Action`` to.
ACTION_CHECK = "hexsos check"
ACTION_REPAIR = "hexsos repair"
ACTIONS = {"check": ACTION_CHECK, "repair": ACTION_REPAIR}

_ROOT = "hexsos"
P_METHOD = f"{_ROOT}/0Parameters/0Method"
P_RELAXATION = f"{_ROOT}/0Parameters/1Relaxation"
P_REPAIR_METHOD = f"{_ROOT}/0Parameters/2Repair method"
P_BOUNDARY = f"{_ROOT}/0Parameters/3Repair boundary"
P_MIN_SJ = f"{_ROOT}/0Parameters/4Target min scaled J"
P_PIN = f"{_ROOT}/0Parameters/5Pin boundary"
P_MAX_ITER = f"{_ROOT}/0Parameters/6Repair iterations"
P_FIX = f"{_ROOT}/0Parameters/7Fix orientation"
# the paper's method only (and the optimizer's fallback to it): after the parameters every repair uses
P_RHO = f"{_ROOT}/0Parameters/8Rho (paper's)"
P_MARGIN = f"{_ROOT}/0Parameters/9Margin (paper's)"
P_CHECK = f"{_ROOT}/1Check"
P_REPAIR = f"{_ROOT}/2Repair"
R_HEXES = f"{_ROOT}/3Results/0Elements checked"
R_INVALID = f"{_ROOT}/3Results/1Invalid"
R_INSIDE_ONLY = f"{_ROOT}/3Results/2Invalid inside only"
R_UNDECIDED = f"{_ROOT}/3Results/3Undecided"
R_MIN_DET = f"{_ROOT}/3Results/4Minimum det J"
R_SKIPPED = f"{_ROOT}/3Results/5Not checked"
R_MESSAGE = f"{_ROOT}/3Results/6Message"
R_MIN_SJ = f"{_ROOT}/3Results/7Minimum scaled J"
R_OTHER = f"{_ROOT}/3Results/8Others not valid"

_LAST = {"result": None, "error": None}
_RESULTS = (R_HEXES, R_INVALID, R_INSIDE_ONLY, R_UNDECIDED, R_MIN_DET, R_SKIPPED, R_MIN_SJ, R_OTHER)


def _parameters(method="auto", relaxation="quad2", rho=200.0, margin="auto", pin=0, max_iter=100,
                repair_method="optimize", boundary="slide", min_sj="auto", fix=0):
    def result(name, label_help):
        return {"type": "number", "name": name, "values": [0], "readOnly": True, "help": label_help,
                "attributes": {"Highlight": "Ivory"}}

    return [
        {"type": "string", "name": P_METHOD, "values": [method], "choices": ["auto", "sos"],
         "help": "auto: Bernstein bounds, SOS only where a hex's bracket stays open; sos: SOS on every trilinear hex "
                 "(the paper)"},
        {"type": "string", "name": P_RELAXATION, "values": [relaxation], "choices": ["quad2", "paper"],
         "help": "quad2: order 2 with u(1-u) >= 0 ...; paper: the paper's relaxation (section 4.2)"},
        {"type": "string", "name": P_REPAIR_METHOD, "values": [repair_method], "choices": ["optimize", "paper"],
         "help": "optimize: untangle, raise the minimum scaled Jacobian, certify every cell; paper: Algorithms 1-2"},
        {"type": "string", "name": P_BOUNDARY, "values": [boundary], "choices": ["slide", "fixed", "free"],
         "help": "slide: boundary nodes stay on the input's boundary surface, features kept; fixed; free "
                 "(the paper's repair: fixed or free)"},
        {"type": "string", "name": P_MIN_SJ, "values": [min_sj], "choices": ["auto", "0.2", "0.3", "0.5"],
         "help": "stop raising the quality once every cell reaches this scaled Jacobian; auto: as high as it goes"},
        {"type": "number", "name": P_PIN, "values": [pin], "choices": [0, 1],
         "help": "keep the boundary nodes where they are during the repair"},
        {"type": "number", "name": P_MAX_ITER, "values": [max_iter], "min": 1, "max": 10000, "step": 10,
         "help": "outer iterations of the repair (optimize: per stage, at most 60 untangling steps and 80 quality "
                 "rounds below 100; paper: Algorithm 2's)"},
        {"type": "number", "name": P_FIX, "values": [fix], "choices": [0, 1],
         "help": "reverse the elements written in the mirrored node order before the repair (those whose faces meet "
                 "their neighbours' the wrong way round fold over them, whatever their nodes' places; off: the "
                 "repair names them and stops)"},
        {"type": "number", "name": P_RHO, "values": [rho], "min": 0.0, "max": 1e4, "step": 10.0,
         "help": "the paper's method (and the optimizer's fallback to it): weight of the averaging step "
                 "(Algorithm 2)"},
        {"type": "string", "name": P_MARGIN, "values": [margin], "choices": ["auto", "1e-4", "1e-3", "1e-2"],
         "help": "the paper's method (and the optimizer's fallback to it): det J >= margin (relative to each "
                 "hex's size) sought; auto: the repair's default"},
        {"type": "string", "name": P_CHECK, "values": [ACTION_CHECK], "label": "Check",
         "attributes": {"Macro": "Action", "Aspect": "Button"},
         "help": "prove every 3-D element valid or invalid (tetrahedra, pyramids, prisms, hexahedra, linear and "
                 "quadratic); posts the views"},
        {"type": "string", "name": P_REPAIR, "values": [ACTION_REPAIR], "label": "Repair",
         "attributes": {"Macro": "Action", "Aspect": "Button"},
         "help": "move the nodes until every element is proven valid, then check again"},
        result(R_HEXES, "3-D elements checked (the Message gives the counts per type)"),
        result(R_INVALID, "elements with a point where det J <= 0 (proven)"),
        result(R_INSIDE_ONLY, "invalid elements that are valid at every node: what corner and node checks miss"),
        result(R_UNDECIDED, "elements neither proven valid nor invalid (e.g. flat)"),
        result(R_MIN_DET, "the smallest det J over all elements, on VTK's reference elements (hexahedra: the cube "
                          "[0,1]^3, Gmsh's minDetJac x 8)"),
        result(R_SKIPPED, "3-D elements of types with no exact element here (13- and 14-node pyramids, orders > 2)"),
        result(R_MIN_SJ, "the smallest corner scaled Jacobian (Verdict's, as HexaLab and ParaView) over the linear cells"),
        result(R_OTHER, "elements other than 8-node hexahedra (tetrahedra, prisms, pyramids, quadratic elements) "
                        "not proven valid"),
        {"type": "string", "name": R_MESSAGE, "values": ["press Check"], "readOnly": True,
         "attributes": {"Highlight": "Ivory"}},
        # the main "Run" button of the ONELAB window runs the check too
        {"type": "string", "name": "ONELAB/Button", "values": ["Check", ACTION_CHECK], "visible": False},
        # the buttons write here; hidden, or the tree shows an editable "Action" field
        {"type": "string", "name": "ONELAB/Action", "values": [""], "visible": False},
    ]


def define_parameters(**defaults) -> None:
    """Create (or reset) the panel's ONELAB parameters. Keyword arguments override the parameter defaults:
    ``method``, ``relaxation``, ``rho``, ``margin`` (``"auto"`` or a number), ``pin`` (0/1), ``max_iter``."""
    gmsh = gmsh_api()
    if "margin" in defaults and not isinstance(defaults["margin"], str):
        defaults["margin"] = "auto" if defaults["margin"] is None else repr(float(defaults["margin"]))
    gmsh.onelab.set(json.dumps({"onelab": {"name": "hexsos", "parameters": _parameters(**defaults)}}))


def _string(name, default):
    gmsh = gmsh_api()
    v = gmsh.onelab.getString(name)
    return v[0] if len(v) else default


def _number(name, default):
    gmsh = gmsh_api()
    v = gmsh.onelab.getNumber(name)
    return float(v[0]) if len(v) else default


def read_parameters() -> dict:
    """The panel's parameters as keyword arguments of :func:`check_model` / :func:`repair_model`.

    Raises InvalidInputError on a value that is not understood (e.g. a margin that is not a number)."""
    method = _string(P_METHOD, "auto").strip()
    relaxation = _string(P_RELAXATION, "quad2").strip()
    margin_s = _string(P_MARGIN, "auto").strip()
    if margin_s.lower() in ("", "auto", "default", "none"):
        margin = None
    else:
        try:
            margin = float(margin_s)
        except ValueError:
            raise InvalidInputError(f"Repair margin: expected 'auto' or a number, found {margin_s!r}") from None
        if not math.isfinite(margin) or margin < 0:
            raise InvalidInputError(f"Repair margin: expected a number >= 0, found {margin_s!r}")
    rho = _number(P_RHO, 200.0)
    max_iter = _number(P_MAX_ITER, 100)
    if not (math.isfinite(rho) and rho >= 0):
        raise InvalidInputError(f"Repair rho: expected a number >= 0, found {rho}")
    if not (math.isfinite(max_iter) and max_iter >= 1):
        raise InvalidInputError(f"Repair max iterations: expected an integer >= 1, found {max_iter}")
    repair_method = _string(P_REPAIR_METHOD, "optimize").strip()
    if repair_method not in ("optimize", "paper"):
        raise InvalidInputError(f"Repair method: expected 'optimize' or 'paper', found {repair_method!r}")
    boundary = _string(P_BOUNDARY, "slide").strip()
    if boundary not in ("slide", "fixed", "free"):
        raise InvalidInputError(f"Repair boundary: expected 'slide', 'fixed' or 'free', found {boundary!r}")
    sj_s = _string(P_MIN_SJ, "auto").strip()
    if sj_s.lower() in ("", "auto", "default", "none"):
        min_sj = None
    else:
        try:
            min_sj = float(sj_s)
        except ValueError:
            raise InvalidInputError(f"Repair target min scaled Jacobian: expected 'auto' or a number in (0, 1), "
                                    f"found {sj_s!r}") from None
        if not (0 < min_sj < 1):
            raise InvalidInputError(f"Repair target min scaled Jacobian: expected a number in (0, 1), found {sj_s!r}")
    return {"method": method, "relaxation": relaxation, "rho": rho, "margin": margin,
            "pin_boundary": bool(_number(P_PIN, 0.0)), "max_iter": int(max_iter), "repair_method": repair_method,
            "boundary": boundary, "min_sj": min_sj, "fix_orientation": bool(_number(P_FIX, 0.0))}


def _highlight(name, colour):
    gmsh = gmsh_api()
    # ONELAB merges a parameter set again: only the given fields change
    p = json.loads(gmsh.onelab.get(name))  # one parameter comes back as a bare object
    if "onelab" in p:
        p = p["onelab"]["parameters"][0]
    p.setdefault("attributes", {})["Highlight"] = colour
    gmsh.onelab.set(json.dumps({"onelab": {"name": "hexsos", "parameters": [p]}}))


def _show_result(result, message: str, *, min_sj=None) -> None:
    gmsh = gmsh_api()
    if min_sj is None:
        q = result.quality()
        min_sj = float("nan") if q is None or q["min"] is None else q["min"]
    gmsh.onelab.setNumber(R_MIN_SJ, [float(min_sj)])
    other = sum(c["cells"] - c["valid"] for t, c in result.by_type().items() if t != "hexahedron")
    gmsh.onelab.setNumber(R_OTHER, [int(other)])
    c = result.counts()
    hx = result.extra.get("gmsh")
    gmsh.onelab.setNumber(R_HEXES, [c["cells"]])
    gmsh.onelab.setNumber(R_INVALID, [c["invalid"]])
    gmsh.onelab.setNumber(R_INSIDE_ONLY, [c["invalid_inside_only"]])
    gmsh.onelab.setNumber(R_UNDECIDED, [c["undecided"]])
    gmsh.onelab.setNumber(R_MIN_DET, [float(np.min(result.min_det))])
    gmsh.onelab.setNumber(R_SKIPPED, [sum(hx.skipped.values()) if hx is not None else 0])
    gmsh.onelab.setString(R_MESSAGE, [message])
    mirrored = result.extra.get("mirrored_element_tags")
    bad = c["invalid"] + c["undecided"] + int(other) + (0 if mirrored is None else len(mirrored)) > 0
    for name in (R_INVALID, R_INSIDE_ONLY, R_UNDECIDED, R_MIN_DET, R_OTHER):
        _highlight(name, "LightPink" if bad else "PaleGreen")


def _fail(message: str) -> None:
    gmsh = gmsh_api()
    gmsh.onelab.setString(R_MESSAGE, [f"error: {message}"])
    gmsh.logger.write(f"hexsos: {message}", "warning")  # "error" makes the API raise


def run_check(**kwargs):
    """Check the current model with the panel's parameters (overridden by ``kwargs``), post the views and
    show the counts in the panel. Returns the CheckResult."""
    p = read_parameters()
    p.update(kwargs)
    result = check_model(method=p["method"], relaxation=p["relaxation"])
    _show_result(result, f"checked {_by_type(result)} in {result.seconds:.3g} s"
                 + _not_checked(result.extra.get("gmsh")) + _mirrored(result))
    return result


def _mirrored(result) -> str:
    """The check's word on elements written in the mirrored node order, and how the panel reverses them."""
    tags = result.extra.get("mirrored_element_tags")
    if tags is None or not len(tags):
        return ""
    shown = ", ".join(map(str, tags[:5])) + (", ..." if len(tags) > 5 else "")
    return (f"; {len(tags)} element{'s' * (len(tags) != 1)} (tags {shown}) written in the mirrored node order "
            "(negative throughout, or folded over their neighbours whatever their own verdicts; Repair with 'Fix "
            "orientation' = 1 reverses them)")


def _by_type(result) -> str:
    """'864 hexahedron (17 invalid, 1 inside only), 12 tetra' and so on."""
    parts = []
    for t, c in result.by_type().items():
        bad = [f"{c['invalid']} invalid"] if c["invalid"] else []
        bad += [f"{c['invalid_inside_only']} inside only"] if c["invalid_inside_only"] else []
        bad += [f"{c['undecided']} undecided"] if c["undecided"] else []
        parts.append(f"{c['cells']} {t}" + (f" ({', '.join(bad)})" if bad else " (all valid)"))
    return ", ".join(parts)


def _not_checked(hx) -> str:
    if hx is None or not hx.skipped:
        return ""
    return "; not checked: " + ", ".join(f"{k} {name}" for name, k in hx.skipped.items())


def run_repair(**kwargs):
    """Repair the current model with the panel's parameters (overridden by ``kwargs``): move its nodes,
    re-check, re-post the views and show the counts. Returns the RepairResult."""
    p = read_parameters()
    p.update(kwargs)
    from hexsos_plugins.meshrepair import door_boundary

    boundary = door_boundary(p["boundary"], p["repair_method"], p["pin_boundary"])
    max_iter = p["max_iter"] if p["repair_method"] == "paper" or p["max_iter"] < 100 else None
    status = _RepairStatus() if gui_available() else None
    res = repair_model(repair_method=p["repair_method"], boundary=boundary, min_sj=p["min_sj"], rho=p["rho"],
                       margin=p["margin"], max_iter=max_iter, method=p["method"], relaxation=p["relaxation"],
                       progress=status and status.progress, callback=status and status.step,
                       fix_orientation=p["fix_orientation"])
    after = res.extra["model_check"]
    c = after.counts()
    s = res.stats
    # success speaks for every 3-D element of the model, re-checked as Gmsh holds it after the repair
    ok = res.success and c["valid"] == c["cells"]
    msg = (f"repair {'succeeded' if ok else 'did not succeed'}: {c['invalid']} invalid, "
           f"{c['undecided']} undecided elements left (" + _by_type(after) + ")"
           + f"; min scaled Jacobian {s.get('min_sj_before', float('nan')):.3f} -> "
           f"{s.get('min_sj_after', float('nan')):.3f}; {len(res.extra['moved_node_tags'])} nodes moved "
           f"(max {s.get('max_displacement', float('nan')):.3g})")
    if len(res.extra["reversed_element_tags"]):
        msg += f"; {len(res.extra['reversed_element_tags'])} elements reversed first (mirrored node order)"
    if "edge_ratio_after" in s:
        msg += (f"; shortest / longest edge of a hex {s['edge_ratio_before']:.3f} -> {s['edge_ratio_after']:.3f}")
    if res.message:
        msg += f"; {res.message}"
    _show_result(after, msg, min_sj=s.get("min_sj_after"))
    return res


class _RepairStatus:
    """Gmsh's status bar during a repair: the cells repaired, the stage under way and the seconds so far (the
    quality stages run on after the last bad cell is repaired), the window redrawn at most every
    :attr:`EVERY` seconds so that it does not freeze for the repair's minute."""

    EVERY = 0.25

    def __init__(self):
        self.t0 = time.perf_counter()
        self.cells = self.words = None
        self._last = -math.inf

    def progress(self, done, total):
        self.cells = (done, total)
        self._show()

    def step(self, entry, points):
        self.words = step_words(entry)
        self._show()
        return False  # never stops the repair

    def text(self) -> str:
        now = time.perf_counter()
        out = "hexsos: repairing"
        if self.cells is not None:
            out += f", {self.cells[0]:,} of {self.cells[1]:,} cells repaired"
        if self.words is not None:
            out += f"; {self.words}, {now - self.t0:.0f} s"
        return out

    def _show(self):
        now = time.perf_counter()
        if now - self._last < self.EVERY:
            return
        self._last = now
        gmsh = gmsh_api()
        gmsh.fltk.setStatusMessage(self.text(), True)
        gmsh.fltk.update()


def gui_available() -> bool:
    """True when the Gmsh GUI is up (``gmsh.fltk`` raises without a display: that is False)."""
    gmsh = gmsh_api()
    try:
        return bool(gmsh.fltk.isAvailable())
    except Exception:
        return False


def _refresh():
    gmsh = gmsh_api()
    if gui_available():
        gmsh.fltk.update()
        gmsh.graphics.draw()


def handle_action(action: str | None = None) -> bool:
    """React to one ONELAB action, as the GUI's event loop does after every event.

    Parameters
    ----------
    action : str, optional
        The action to run; default: the value of ``ONELAB/Action`` (set by the buttons). The action is
        consumed: ``ONELAB/Action`` is reset to "".

    Returns
    -------
    bool
        True to keep the event loop running (always, except for the action "hexsos quit"). Errors of the
        check or repair (no hexahedra, a bad parameter, ...) do not stop the loop: they are shown in the
        panel's Message and Gmsh's message console.
    """
    gmsh = gmsh_api()
    if action is None:
        value = gmsh.onelab.getString("ONELAB/Action")
        action = value[0] if len(value) else ""
    if not action:
        return True
    gmsh.onelab.setString("ONELAB/Action", [""])
    if action == "reset":  # "Reset database" in the GUI
        define_parameters()
    elif action in (ACTION_CHECK, ACTION_REPAIR):
        what = "checking" if action == ACTION_CHECK else "repairing"
        if gui_available():
            gmsh.fltk.setStatusMessage(f"hexsos: {what}...", True)
        _LAST["result"] = _LAST["error"] = None
        try:
            _LAST["result"] = (run_check if action == ACTION_CHECK else run_repair)()
        except HexsosError as exc:
            _LAST["error"] = exc
            _fail(str(exc))
        if gui_available():
            gmsh.fltk.setStatusMessage("", True)
    elif action == "hexsos quit":
        return False
    # anything else ("check": the database changed, actions of other panels) needs nothing from us
    _refresh()
    return True


def widen_menu(width: int = 430) -> None:
    """Before ``gmsh.fltk.initialize()``: make the tree wide enough for the panel's labels (Gmsh's default,
    200 pixels, cuts them), widening the window by as much so the graphics keep their size."""
    gmsh = gmsh_api()
    menu = gmsh.option.getNumber("General.MenuWidth")
    if menu < width:
        gmsh.option.setNumber("General.MenuWidth", width)
        gmsh.option.setNumber("General.GraphicsWidth", gmsh.option.getNumber("General.GraphicsWidth") + width - menu)


def last_result():
    """The result of the last check or repair run by :func:`handle_action` (None before the first, and
    after one that failed: then :func:`last_error` holds the exception)."""
    return _LAST["result"]


def last_error():
    """The HexsosError the last check or repair run by :func:`handle_action` raised, or None."""
    return _LAST["error"]


def event_loop(*, auto_action: str | None = None, screenshot: str | None = None, exit_after: bool = False):
    """Open the Gmsh GUI with the panel and run its event loop until the window closes.

    ``auto_action`` ("check" or "repair") is triggered once at start, by setting ``ONELAB/Action`` as its
    button does; once it has run, ``screenshot`` (a .png/.jpg/... path) is saved and, with ``exit_after``,
    the loop ends. A ``screenshot`` without ``auto_action`` is the picture of the model as opened: taken once
    the window is drawn, and the loop ends (there is nothing else to wait for). Raises whatever
    ``gmsh.fltk.initialize`` raises when there is no display.

    Returns the result of the last check or repair run from the loop, or None.
    """
    gmsh = gmsh_api()
    if not gui_available():
        widen_menu()
        gmsh.fltk.initialize()
    try:
        gmsh.fltk.openTreeItem(_ROOT)
    except Exception:  # cosmetic only
        pass
    _LAST["result"] = _LAST["error"] = None
    pending = ACTIONS[auto_action] if auto_action else None
    if pending:
        gmsh.onelab.setString("ONELAB/Action", [pending])
    elif screenshot:  # the picture of the model as opened, then done
        gmsh.fltk.wait(0.05)
        gmsh.graphics.draw()
        gmsh.write(screenshot)
        return _LAST["result"]
    while gmsh.fltk.isAvailable():
        current = gmsh.onelab.getString("ONELAB/Action")
        current = current[0] if len(current) else ""
        if not handle_action():
            break
        if pending and current == pending:
            pending = None
            if screenshot:
                gmsh.fltk.wait(0.05)
                gmsh.graphics.draw()
                gmsh.write(screenshot)
            if exit_after:
                break
        gmsh.fltk.wait()
    return _LAST["result"]
