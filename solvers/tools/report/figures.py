"""The review page's plots as plotly figure specifications, with their bulk data in a ``Blob``.

Each figure is ``{"id", "title", "time", "layout", "traces"}``; a trace is ``{"trace": <plotly trace
attributes>, "x": <blob array>, "y": <blob array> or [<blob array>, row]}`` when its points come from
the blob (the page reduces them to the min/max envelope of the visible frames, again on every zoom),
or carries its points inline. ``time`` figures share the frame axis: zooming one zooms them all.
"""

import numpy as np

from .regions import face_regions
from .review import head_motion

#: Weight curves shown at first (the others one click away in the legend).
SHOWN_SHAPES = 8
#: Heat map columns over the whole take (each the worst of its frames).
HEAT_COLUMNS = 1200
#: Flag marks at most (one per screen bucket).
FLAG_MARKS = 2000
#: Worst frames marked on the residual plot.
WORST_MARKED = 10
AXIS = {"title": {"text": "frame"}, "zeroline": False}
#: The top margin holds plotly's mode bar (its buttons are about 30 px high): the legend, which starts at the
#: top of the plot area, is never under it.
TOP = 38
BASE_LAYOUT = {"margin": {"l": 60, "r": 20, "t": TOP, "b": 40}, "showlegend": True, "hovermode": "x unified",
               "uirevision": "keep", "plot_bgcolor": "#fbfbfb", "paper_bgcolor": "#ffffff",
               "font": {"family": "system-ui, sans-serif", "size": 12}}
AXES_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")  # X, Y, Z as Blender draws them
#: Heat map colours: small errors pale, large ones dark red.
HEAT_SCALE = [[0.0, "#fffff2"], [0.35, "#fed976"], [0.65, "#fd8d3c"], [0.85, "#e31a1c"], [1.0, "#800026"]]


def colour(i):
    """A distinct colour for curve ``i`` (golden-angle hues)."""
    return f"hsl({(i * 137.508) % 360:.0f}, 62%, 42%)"


def _layout(height, yaxis, **extra):
    return {**BASE_LAYOUT, "height": height, "xaxis": dict(AXIS), "yaxis": yaxis, **extra}


def _line(name, y, *, x="frames", colour_=None, dash=None, width=1.5, visible=True, group=None, hover=".3f",
          rank=None, legend=True):
    line = {"width": width}
    if colour_:
        line["color"] = colour_
    if dash:
        line["dash"] = dash
    trace = {"type": "scatter", "mode": "lines", "name": name, "line": line,
             "hovertemplate": f"%{{y:{hover}}}", "connectgaps": False}
    if visible is not True:
        trace["visible"] = visible
    if group:
        trace["legendgroup"] = group
    if rank is not None:  # the shapes shown first come first in the legend
        trace["legendrank"] = rank
    if not legend:
        trace["showlegend"] = False
    return {"trace": trace, "x": x, "y": y}


def build_figures(review, blob):
    """The page's figures for ``review`` (a Review); their arrays go into ``blob``. Returns a list."""
    result = review.result
    blob.add_exact("frames", result.frames)
    figures = [_weights(review, blob)]
    if np.isfinite(result.residual_rms).any():
        figures.append(_residual(result, blob))
    if result.frame_marker_residual is not None and np.isfinite(result.frame_marker_residual).any():
        figures.append(_heat(result, review))
    head = head_motion(result.stabilise)
    if head is not None:
        figures += _head(head, blob, np.asarray(result.frames, dtype=np.float64))
    elif review.head_angles is not None:  # a phone's own head angles (Live Link Face): nothing was removed
        figures.append(_phone_head(review.head_angles, blob))
    return figures


def shown_shapes(weights, count=SHOWN_SHAPES):
    """Indices of the ``count`` shapes with the largest peak weight."""
    peak = np.nanmax(np.where(np.isfinite(weights), np.abs(weights), -np.inf), axis=0) if weights.size else []
    return set(np.argsort(-np.asarray(peak), kind="stable")[:count].tolist())


def _weights(review, blob):
    result = review.result
    blob.add("weights", np.asarray(result.weights, dtype=np.float64).T, 1e-3)
    shown = shown_shapes(np.asarray(result.weights, dtype=np.float64))
    traces = [{**_line(name, ["weights", k], colour_=colour(k), visible=True if k in shown else "legendonly",
                       group=name, rank=k if k in shown else 1000 + k), "shown": k in shown}
              for k, name in enumerate(result.shape_names)]
    truth = review.truth_values
    if truth is not None:
        have = np.isfinite(truth).any(axis=0)
        blob.add("truth", truth.T, 1e-3)
        # no legend entry of their own: a shape's entry shows and hides its truth too (one legend group)
        traces += [{**_line(f"{name} (truth)", ["truth", k], colour_=colour(k), dash="dot", width=1.2,
                            visible=True if k in shown else "legendonly", group=name, legend=False),
                    "shown": k in shown} for k, name in enumerate(result.shape_names) if have[k]]
    layout = _layout(460, {"title": {"text": "weight"}, "zeroline": False},
                     legend={"font": {"size": 11}, "itemclick": "toggle", "itemdoubleclick": "toggleothers"})
    layout["xaxis"]["rangeslider"] = {"visible": True, "thickness": 0.07}
    return {"id": "weights", "title": "", "time": True, "layout": layout, "traces": traces}


def worst_rows(residual, count=WORST_MARKED, spacing=1):
    """Rows of the ``count`` largest finite values of ``residual``, at least ``spacing`` rows apart."""
    order = np.argsort(np.where(np.isfinite(residual), -residual, np.inf), kind="stable")
    out = []
    for i in order[np.isfinite(residual[order])]:
        if len(out) == count:
            break
        if all(abs(int(i) - j) >= spacing for j in out):
            out.append(int(i))
    return out


def _residual(result, blob):
    residual_mm = np.asarray(result.residual_rms, dtype=np.float64) * 1e3
    blob.add("residual", residual_mm, 1e-4)
    rows = worst_rows(residual_mm, spacing=max(1, result.frames.size // 200))
    frames = result.frames[rows]
    # no text labels on the plot (close worst frames made them collide): the page lists them under it
    worst = {"trace": {"type": "scatter", "mode": "markers", "name": "worst frames",
                       "x": [float(f) for f in frames], "y": [round(float(residual_mm[i]), 4) for i in rows],
                       "marker": {"color": "#d62728", "size": 8, "symbol": "circle-open", "line": {"width": 2}},
                       "hovertemplate": "worst frame %{x}: %{y:.3f} mm<extra></extra>"}}
    where = {"character": "on the character", "actor": "on the actor's markers"}.get(result.residual_space, "")
    line = _line(f"RMS residual ({where})" if where else "RMS residual", "residual", colour_="#444", hover=".3f")
    layout = _layout(260, {"title": {"text": "mm"}, "rangemode": "tozero"}, hovermode="closest")
    return {"id": "residual", "title": "Residual per frame", "time": True, "layout": layout,
            "traces": [line, worst], "worst": [[float(f), round(float(residual_mm[i]), 3)] for f, i in zip(frames, rows)]}


def heat_columns(frames, values, columns=HEAT_COLUMNS):
    """Per-marker values (F, M) reduced to at most ``columns`` time columns, each the maximum of its
    frames (a bad frame is never averaged away). Returns (column centre frames (C,), (M, C))."""
    F = values.shape[0]
    columns = min(columns, F)
    edges = (np.arange(columns + 1) * F) // columns
    filled = np.where(np.isfinite(values), values, -np.inf)
    top = np.maximum.reduceat(filled, edges[:-1], axis=0).T
    top[~np.isfinite(top)] = np.nan
    centres = 0.5 * (frames[edges[:-1]] + frames[edges[1:] - 1])
    return centres, top


def _heat(result, review=None):
    per = np.asarray(result.frame_marker_residual, dtype=np.float64) * 1e3
    centres, top = heat_columns(np.asarray(result.frames, dtype=np.float64), per)
    zmax = float(np.nanpercentile(per, 99.5)) if np.isfinite(per).any() else 1.0
    names = list(result.marker_names)
    groups = marker_groups(names, review)
    order = [names.index(n) for _, members in groups for n in members]
    top = top[order]
    z = np.round(top, 3).astype(object)
    z[~np.isfinite(top)] = None
    rows = [names[i] for i in order]
    span = "" if centres.size == result.frames.size else f" (each column the worst of {result.frames.size / centres.size:.0f} frames)"
    trace = {"type": "heatmap", "name": "marker error", "x": [round(float(c), 3) for c in centres], "y": rows,
             "z": z.tolist(), "zmin": 0.0, "zmax": round(zmax, 4), "colorscale": HEAT_SCALE,
             "colorbar": {"title": {"text": "mm"}, "thickness": 12, "xref": "container", "x": 1.0, "xanchor": "right"},
             "hovertemplate": "%{y}<br>frame %{x:.0f}<br>%{z:.3f} mm<extra></extra>"}
    # a line between face regions and the region's name beside its rows
    shapes, notes, first = [], [], 0
    for region, members in groups:
        last = first + len(members) - 1
        if first:
            shapes.append({"type": "line", "xref": "paper", "x0": 0, "x1": 1, "yref": "y", "y0": first - 0.5,
                           "y1": first - 0.5, "line": {"color": "#333", "width": 1.5}})
        notes.append({"xref": "paper", "x": 1.005, "xanchor": "left", "yref": "y", "y": 0.5 * (first + last),
                      "text": region, "showarrow": False, "font": {"size": 11, "color": "#333"}})
        first = last + 1
    layout = _layout(140 + 11 * len(rows), {"automargin": True, "tickfont": {"size": 9}, "autorange": "reversed"},
                     hovermode="closest", showlegend=False, margin={"l": 130, "r": 190, "t": TOP, "b": 40},
                     shapes=shapes, annotations=notes)
    return {"id": "heat", "title": f"Error per marker over time, by face region{span}", "time": True,
            "layout": layout, "traces": [{"trace": trace}]}


def marker_groups(names, review=None):
    """The heat map's rows by face region (``regions.face_regions``): names, stable markers and, for names
    that say nothing, each marker's height on the character (the review's binding)."""
    settings = getattr(review, "settings", None)
    stable = () if settings is None else tuple(getattr(settings, "stable_markers", ()) or ())
    geometry = getattr(review, "geometry", None)
    points = None
    if geometry is not None:
        where = {n: p for n, p in zip(geometry.names, np.asarray(geometry.bound, dtype=np.float64))}
        points = np.array([where.get(n, (np.nan,) * 3) for n in names], dtype=np.float64)
    return face_regions(names, stable=stable, points=points)


def _phone_head(angles, blob):
    """The head's rotation as the phone measured it (Live Link Face yaw, pitch, roll), in degrees."""
    blob.add("head_rotation", np.degrees(np.asarray(angles, dtype=np.float64)).T, 1e-3)
    names = ("yaw (turn)", "pitch (nod)", "roll (tilt)")
    return {"id": "head_rotation", "title": "Head rotation as the phone measured it", "time": True,
            "layout": _layout(240, {"title": {"text": "degrees"}}),
            "traces": [_line(n, ["head_rotation", i], colour_=AXES_COLOURS[i], hover=".2f") for i, n in enumerate(names)]}


def _head(head, blob, frames):
    unit = head["units"]
    rot, trans = head["rotation"], head["translation"]
    blob.add("head_rotation", rot.T, 1e-3)
    blob.add("head_translation", trans.T, 1e-3)
    blob.add("stable_rms", head["rms"], 1e-4)
    axes = "XYZ" if rot.shape[1] == 3 else ("in-plane",)
    figs = [
        {"id": "head_rotation", "title": "Removed head rotation", "time": True,
         "layout": _layout(240, {"title": {"text": "degrees"}}),
         "traces": [_line(f"about {a}" if len(a) == 1 else a, ["head_rotation", i], colour_=AXES_COLOURS[i % 3],
                          hover=".2f") for i, a in enumerate(axes)]},
        {"id": "head_translation", "title": "Removed head translation (the head's centre)", "time": True,
         "layout": _layout(240, {"title": {"text": unit}}),
         "traces": [_line(f"along {'XYZ'[i]}", ["head_translation", i], colour_=AXES_COLOURS[i % 3], hover=".2f")
                    for i in range(trans.shape[1])]},
    ]
    flags = []
    for key, label, col, symbol in (("flagged", "not stabilised (flagged)", "#d62728", "x"),
                                    ("unreliable", "unreliable head fit", "#ff7f0e", "triangle-up")):
        rows = np.flatnonzero(head[key])
        count = rows.size
        if count > FLAG_MARKS:  # one mark per screen bucket is all the eye can tell apart
            _, first = np.unique(rows * FLAG_MARKS // len(frames), return_index=True)
            rows = rows[first]
        flags.append({"trace": {"type": "scatter", "mode": "markers", "name": f"{label}: {count} frames",
                                "x": [float(f) for f in frames[rows]], "y": [0.0] * rows.size,
                                "marker": {"color": col, "symbol": symbol, "size": 7},
                                "hovertemplate": f"{label}<extra></extra>"}})
    figs.append({"id": "stabilise", "title": "Stabilisation: stable-marker fit and flags", "time": True,
                 "layout": _layout(240, {"title": {"text": unit}, "rangemode": "tozero"}, hovermode="closest"),
                 "traces": [_line("stable-marker fit RMS", "stable_rms", colour_="#444", hover=".3f"), *flags]})
    return figs


def binding_figure(geometry):
    """A bar per marker: its distance from its bound point after the actor->character alignment."""
    order = np.argsort(-np.nan_to_num(geometry.binding_mm, nan=-1.0), kind="stable")
    names = [geometry.names[i] for i in order]
    values = [None if not np.isfinite(geometry.binding_mm[i]) else round(float(geometry.binding_mm[i]), 3)
              for i in order]
    flagged = set(getattr(geometry.alignment, "flagged", ()))
    colours = ["#d62728" if n in flagged else "#1f77b4" for n in names]
    trace = {"type": "bar", "name": "binding distance", "x": names, "y": values, "marker": {"color": colours},
             "hovertemplate": "%{x}: %{y:.2f} mm<extra></extra>"}
    layout = {**BASE_LAYOUT, "height": 280, "showlegend": False, "hovermode": "closest",
              "xaxis": {"tickangle": -60, "tickfont": {"size": 9}, "automargin": True},
              "yaxis": {"title": {"text": "mm"}, "rangemode": "tozero"}}
    return {"id": "binding", "title": "Binding distance per marker", "time": False, "layout": layout,
            "traces": [{"trace": trace}]}
