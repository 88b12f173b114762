"""What a lost unit had already swept of its search (pure; docs/protocol.md §11, DESIGN 3.11).

A lost unit's part of a search is not flown again whole: what it swept is subtracted, and only the
remainder is planned again (shared among the live units by the planner, `allocation.share_plan`).

How progress is known: from the **positions the unit reported** (``sensor/position``, kept by the
fleet registry) since its task started running: the track through them, ``w/2`` either side
(``w`` its sweep width for the search), is swept. Not the time spent along its lane path: a unit
paused, slowed by wind, or still flying to its sweep's start would be credited with lanes it never
flew, and the path a unit flies is its own (a real unit plans its own lanes; even ours depend on
the frame a tie is broken in). The track errs the safe way: what the unit flew after its last
position was heard is flown again. Two positions more than ``MAX_CHORD`` lane widths apart are not
joined (a gap in the reports: what lies between is not credited).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import shapely

from delegation.allocation.share_plan import searched_over
from delegation.allocation.sharing import pieces_xy, region_of
from delegation.costs import search_polygons_xy, sweep_width, task_geometry
from delegation.coverage import footprint
from delegation.fleet import UnitState
from delegation.geo import GeoPoint, LocalFrame
from delegation.tst.node import TstNode

#: A remainder under this share of the part is not worth a flight: nothing is subtracted (the
#: part is flown again whole) rather than leaving a task of nothing.
MIN_REMAINDER = 0.02
#: A credit under this share of the part is the remainder's rounded corners, not progress.
MIN_CREDIT = 0.02
#: Tolerance (m) to which the remainder's outline is simplified.
SIMPLIFY_M = 0.5
#: Consecutive positions farther apart than this many sweep widths are a gap, not a flight.
MAX_CHORD = 3.0


def swept_region(track_xy: np.ndarray, width: float) -> shapely.Geometry:
    """What a sensor ``width`` m wide swept along the track (east/north m): each run of positions
    closer than ``MAX_CHORD`` widths, joined, seen by the camera's square footprint (as
    the sweeps are planned and the simulated units are judged: `coverage.footprint`)."""
    if len(track_xy) == 0:
        return shapely.Polygon()
    steps = np.hypot(*np.diff(track_xy, axis=0).T) if len(track_xy) > 1 else np.zeros(0)
    cuts = np.flatnonzero(steps > MAX_CHORD * width) + 1
    runs = np.split(track_xy, cuts)
    return shapely.union_all([footprint(r, width) for r in runs])


def remainder(node: TstNode, unit: UnitState, track: Sequence[GeoPoint]
              ) -> tuple[float, shapely.Geometry, LocalFrame] | None:
    """(share of the area swept, what is left of it as a region in metres, its frame) for the
    search ``node`` flown by ``unit`` along ``track``; None for a task that is not a search."""
    geometry = task_geometry(node)
    if geometry.kind != "areas":
        return None
    frame = LocalFrame.around([p for area in geometry.areas for p in area]
                              + list(geometry.points))
    region = region_of(search_polygons_xy(node, frame))
    if region.is_empty or region.area <= 0.0:
        return None
    width = sweep_width(unit, geometry.target_size)
    swept = swept_region(frame.points_xy(list(track)), width)
    left = shapely.difference(region, swept)
    # Slivers thinner than a quarter lane are the swept strips' ragged edges, not work left
    # (thicker ones are real: a unit that turns early leaves a strip along the border unseen).
    left = left.buffer(-width / 8.0).buffer(width / 8.0).intersection(region)
    # The rounded edges' many points, simplified to 0.5 m and grown by as much (never less).
    left = shapely.simplify(left, SIMPLIFY_M).buffer(SIMPLIFY_M, join_style="mitre")
    left = left.intersection(region)
    done = 1.0 - float(left.area) / float(region.area)
    return max(0.0, min(1.0, done)), left, frame


def unswept(node: TstNode, unit: UnitState, track: Sequence[GeoPoint]) -> tuple[TstNode, float]:
    """The search ``node`` reduced to what ``unit`` had not swept along ``track``, and the share
    of its area credited as swept (0.0 and the node itself when under ``MIN_CREDIT`` is, or when
    under ``MIN_REMAINDER`` is left: not worth a task)."""
    found = remainder(node, unit, track) if track else None
    if found is None:
        return node, 0.0
    done, left, frame = found
    pieces = pieces_xy(left)
    if done < MIN_CREDIT or not pieces or 1.0 - done < MIN_REMAINDER:
        return node, 0.0
    name, params = searched_over(node, pieces, frame)
    return replace(node, name=name, params=params, key_order=()), done
