"""The annotation engine (the T-Analyst replacement): keyframes, interpolation, a crash-safe edit
journal, placement from pixels and masks, review aids. No UI imports: the app sits on top.

    from annotate import Project
    with Project.open("scene", run="runs/baseline") as p:   # run: optional Seg2Pose output
        ch = p.create_track("car")                           # -> Change(tracks={1}, created={1})
        p.set_keyframe(ch.track, 0, 3.0, -1.5, heading=0.0)
        p.set_keyframe(ch.track, 25, 12.0, -1.4)
        table = p.poses()                                    # PoseTable + size, source
        p.undo()

See ``Project`` (project.py) for opening/undo/notification, edits.py for the edits,
interpolate.py for the interpolants, table.py for the poses table, journal.py for the files.
"""

from annotate.interpolate import CLASS_METHODS, METHODS, default_method
from annotate.journal import JournalError, LockedError, NotSavedError
from annotate.model import FLAGS, SPAN_KINDS, EditError, Keyframe, Track
from annotate.project import Change, Project
from annotate.table import SOURCES

__all__ = ["Project", "Change", "Track", "Keyframe",
           "default_method", "METHODS", "CLASS_METHODS", "SOURCES", "SPAN_KINDS", "FLAGS",
           "EditError", "JournalError", "LockedError", "NotSavedError"]
