"""What a repair returns, whichever method ran: :class:`RepairResult` and its printed summary.

Imports the certify wing (the certificate's type) only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..certify import CheckResult
from ..cells.quality import SHORT_EDGE_RATIO, sj_text
from .boundary import TILT_DEGREES

__all__ = ["RepairResult", "readonly", "step_words"]


# the repair's stages (its history's names) in the words a progress line shows
_STAGE_WORDS = {"untangle": "untangling", "untangle (local)": "untangling", "smooth": "smoothing",
                "quality": "raising the quality", "local": "vertex steps", "joint": "joint steps",
                "straighten": "standing quads back up", "into the band": "back into the band",
                "skeleton": "untangling the straight skeleton"}
_HELD = ", boundary held"


def step_words(entry: dict) -> str:
    """The stage of a history entry (what a repair's ``callback`` receives) in words: ``"joint steps"``,
    ``"untangling, boundary held"`` (the boundary's second run: ``boundary_held`` in the entry), ``"iteration 3"``
    (the paper's method)."""
    stage = entry.get("stage", f"iteration {entry.get('iteration', 0)}")
    return _STAGE_WORDS.get(stage, stage) + (_HELD if entry.get("boundary_held") else "")


@dataclass
class RepairResult:
    """What :func:`repair` returns.

    Attributes
    ----------
    points : (N, 3) float64, the repaired coordinates (a new array; the best mesh seen if not successful)
    success : bool, every hex proven valid by the final :func:`hexsos_plugins.check` (default settings)
    check : CheckResult, that final check on the repaired mesh
    history : list of dict, one per outer iteration (iteration 0 is the input): ``iteration``, ``invalid``
        (hexes proven invalid), ``undecided``, ``min_det`` (smallest over the mesh), ``sos_steps``,
        ``projection_steps``, ``moved_vertices``, ``seconds`` (of that iteration)
    stats : dict, the paper's Table 1 columns and more (see :func:`repair`)
    displacement : (N, 3) float64, ``points - input points``
    message : str, why it stopped
    """

    points: np.ndarray
    success: bool
    check: CheckResult
    history: list
    stats: dict
    displacement: np.ndarray
    message: str
    extra: dict = field(default_factory=dict)

    def summary(self) -> str:
        s = self.stats
        if s.get("method") == "curved":
            return summary_curved(self)
        if s.get("method") != "paper":
            return summary_optimize(self)
        lines = [
            "method            paper (Algorithms 1 and 2)",
            f"hexes             {s['hexes']}",
            f"invalid before    {s['invalid_before']} (undecided {s['undecided_before']})",
            f"invalid after     {s['invalid_after']} (undecided {s['undecided_after']})",
            f"outer iterations  {s['outer_iterations']}",
            f"SOS steps         {s['sos_steps']} (kernel evaluations per hex; SDP solves {s['sdp_solves']})",
            f"(R) steps         {s['projection_steps']}",
            f"displacement      max {s['max_displacement']:.6g}, mean {s['mean_displacement']:.6g} over "
            f"{s['moved_vertices']} moved vertices"
            + (f", {s['pinned_vertices']} pinned" if s["pinned_vertices"] else ""),
        ]
        if "min_sj_after" in s:
            lines.append(sj_line(s))
        lines += [
            f"monotone invalid  {s['monotone_invalid']}",
            f"time              {s['seconds']:.3f} s",
            f"result            {'certified: every hex proven valid' if self.success else 'NOT all hexes proven valid'}",
            f"                  {self.message}",
        ]
        return "\n".join(lines)

    def __repr__(self) -> str:
        s = self.stats
        return (f"RepairResult(success={self.success}, hexes={s['hexes']}, invalid_before={s['invalid_before']}, "
                f"invalid_after={s['invalid_after']}, outer_iterations={s['outer_iterations']})")




def sj_line(s):
    t = {k: sj_text(s[k]) for k in ("min_sj_before", "min_sj_after", "p1_sj_before", "p1_sj_after",
                                     "mean_sj_before", "mean_sj_after")}
    line = (f"scaled Jacobian   min {t['min_sj_before']} -> {t['min_sj_after']}, 1st percentile "
            f"{t['p1_sj_before']} -> {t['p1_sj_after']}, mean {t['mean_sj_before']} -> {t['mean_sj_after']}")
    if "edge_ratio_after" in s:
        line += (f"\nedge ratio        shortest / longest edge of a hex, least {s['edge_ratio_before']:.4f} -> "
                 f"{s['edge_ratio_after']:.4f}; hexes below {SHORT_EDGE_RATIO:g}: {s['short_edge_hexes_before']} -> "
                 f"{s['short_edge_hexes_after']}")
    return line


def _leash_lines(info):
    """The report's line on the second run with boundary vertices held near their input positions, if it ran or
    was due (:func:`hexsos_plugins.meshrepair.driver.repair`'s ``stats["boundary_leash"]``)."""
    if not info or not info.get("vertices"):
        return []
    head = (f"boundary leash    the boundary ended {100 * info['deviation']:.2f}% of the diagonal from the input's; "
            f"{info['vertices']} boundary vertices there")
    if not info.get("run"):
        return [head + f" were not held ({info.get('why', 'not run')})"]
    return [head + f" held within {100 * info['radius']:g}% of it of their input positions in a second run: "
            + (f"{100 * info['deviation_leashed']:.2f}%" if info["deviation_leashed"] is not None else "not certified")
            + f", min SJ {sj_text(info['min_sj_free'])} -> {sj_text(info['min_sj_leashed'])}, "
            + ("kept" if info["kept"] else "not kept (the first run's mesh is returned)")
            + f" ({info['seconds']:.1f} s)"]


def summary_optimize(res):
    s = res.stats
    other = ""
    if s.get("other_cells"):
        other = (f"other cells       {s['other_cells']} ({', '.join(f'{k} {v}' for k, v in s['other_cell_types'].items())}):"
                 f" invalid {s['other_cells_invalid_before']} -> {s['other_cells_invalid_after']} "
                 f"({s['other_cells_check']})")
    st = s.get("stage_seconds", {})
    lines = [
        f"method            {s['method']} (untangle, raise the min scaled Jacobian, certify); boundary {s['boundary']}",
        f"hexes             {s['hexes']}",
        f"invalid before    {s['invalid_before']} (undecided {s['undecided_before']})",
        f"invalid after     {s['invalid_after']} (undecided {s['undecided_after']})",
    ] + ([other] if other else []) + [
        f"min det J         {s['min_det_before']:.6g} -> {s['min_det_after']:.6g} (exact, the kernel's)",
    ] + ([f"det J min / max   {s['det_ratio_before']:.4f} -> {s['det_ratio_after']:.4f} (the least over the hexes "
          "of min det J / max |det J|)"] if "det_ratio_after" in s else []) + [
        sj_line(s),
        f"displacement      max {s['max_displacement']:.6g}, mean {s['mean_displacement']:.6g} over "
        f"{s['moved_vertices']} moved vertices of {s['points']}"
        + (f" ({s['moved_over_1pct']} by more than 1% of the bounding-box diagonal)" if "moved_over_1pct" in s else "")
        + (f", {s['pinned_vertices']} pinned" if s["pinned_vertices"] else "")
        + (f", {s['released_corners']} feature corners released (they held cells not valid)"
           if s.get("released_corners") else "")
        + (f"; local: only the {s['local_region_vertices']} vertices within {s['rings']} rings of the "
           f"cells not proven valid could move" if s.get("local") else ""),
    ] + ([f"surface           {s['turned_quads_before']} -> {s['turned_quads_after']} boundary quads turned over "
          "(facing against their input normal: the surface folded there"
          + (f"; {s['unturned_quads']} turned back out at the end" if s.get("unturned_quads") else "") + ")"
          + (f"; {s['tilted_quads_before']} -> {s['tilted_quads_after']} of {s['boundary_quads']} tilted more than "
             f"{TILT_DEGREES:g} degrees from it" if "tilted_quads_after" in s else "")
          + (f" ({s['untilted_quads']} stood back up at the end)" if s.get("untilted_quads") else "")]
         if "turned_quads_after" in s else []) + _leash_lines(s.get("boundary_leash")) + [
        f"stages            untangle {st.get('untangle', 0):.2f} s ({s['untangle_iterations']} iterations), quality "
        f"{st.get('quality', 0):.2f} s ({s['quality_rounds']} rounds"
        + (f", the last {s['quality_rounds_undone']} undone: they ended below where they began"
           if s.get("quality_rounds_undone") else "")
        + (f"; {s['quality_chunks_kept_below']} chunk{'s' * (s['quality_chunks_kept_below'] != 1)} of them ended "
           "below their start, kept: the vertex steps from there rose past it" if s.get("quality_chunks_kept_below")
           else "") + ")"
        + (f", vertex steps {st['local']:.2f} s ({s.get('local_steps', 0)} steps)" if "local" in st else "")
        + (f", joint steps {st['joint']:.2f} s ({s.get('joint_steps', 0)} kept)" if "joint" in st else "")
        + (f" ({s['joint_past_budget']:.2f} s of them past their budget, while they gained)"
           if "joint" in st and s.get("joint_past_budget") else "")
        + f", certify {st.get('certify', 0):.2f} s"
        + (f", fallback (paper) {st['fallback']:.2f} s" if "fallback" in st else ""),
        f"time              {s['seconds']:.3f} s",
        f"result            {'certified: every cell proven valid' if res.success else 'NOT every cell proven valid'}",
        f"                  {res.message}",
    ]
    return "\n".join(lines)


def summary_curved(res):
    s = res.stats
    st = s.get("stage_seconds", {})
    lines = [
        f"method            curved (a barrier on det J's Bernstein coefficients, certify); boundary {s['boundary']}",
        f"cells             {s['cells']} ({', '.join(f'{k} {v}' for k, v in s['cell_types'].items())})",
        f"invalid before    {s['invalid_before']} (undecided {s['undecided_before']})",
        f"invalid after     {s['invalid_after']} (undecided {s['undecided_after']})",
        f"min det J         {s['min_det_before']:.6g} -> {s['min_det_after']:.6g} (the kernel's)",
        f"curved scaled J.  min {sj_text(s['curved_sj_before'])} -> {sj_text(s['curved_sj_after'])} (min / max of "
        "det J's Bernstein coefficients, proven)",
        sj_line(s) + " (corners)",
        f"displacement      max {s['max_displacement']:.6g}, mean {s['mean_displacement']:.6g} over "
        f"{s['moved_vertices']} moved nodes" + (f", {s['pinned_vertices']} pinned" if s["pinned_vertices"] else ""),
    ] + ([f"boundary          nodes within {s['boundary_max_distance']:.3g} of the input's curved faces"]
         if "boundary_max_distance" in s else []) + [
        "stages            "
        + (f"skeleton {st.get('skeleton', 0):.2f} s ({s.get('skeleton_folded_before', 0)} -> "
           f"{s.get('skeleton_folded_after', 0)} folded straight-sided cells), " if s.get("skeleton_folded_before") else "")
        + f"untangle {st.get('untangle', 0):.2f} s ({s['untangle_iterations']} iterations), quality "
        f"{st.get('quality', 0):.2f} s ({s['quality_rounds']} rounds), certify {st.get('certify', 0):.2f} s",
        f"time              {s['seconds']:.3f} s",
        f"result            {'certified: every cell proven valid' if res.success else 'NOT every cell proven valid'}",
        f"                  {res.message}",
    ]
    return "\n".join(lines)


def readonly(a):
    """A read-only view of an array (what a repair's callback is handed)."""
    v = a.view()
    v.flags.writeable = False
    return v
