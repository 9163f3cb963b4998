"""The support: the table under the workpiece, found as the plane below everything."""

from __future__ import annotations

import numpy as np

from perception.fine.support import find_support

from .scenes import rendered, work


def test_the_table_is_the_support_and_no_workpiece_face_is() -> None:
    for name in ("tee", "pipe", "butt"):
        res = rendered(name, "stereo")
        p, _, nm, surf = work(name, "stereo")
        sup = find_support(p, surf, nm)
        assert sup, name
        for lab in sup:
            m = surf.labels == lab
            assert np.mean(res.part_index[m] == 0) > 0.99, (name, lab)
        # every big surface on the table's plane is in the set (the table seen on both sides of a part)
        for s in surf.surfaces:
            m = surf.labels == s.label
            if s.n_points > 2000 and np.mean(res.part_index[m] == 0) > 0.99:
                assert s.label in sup, (name, s.label)


def test_a_prompted_surface_is_never_the_support() -> None:
    p, _, nm, surf = work("tee")
    sup = find_support(p, surf, nm)
    assert find_support(p, surf, nm, prompted=frozenset(sup)) != sup
