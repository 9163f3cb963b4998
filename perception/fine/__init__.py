"""The fine stage, surfaces first: one step per module, each a pure function on small frozen value types.

    organized cloud (work resolution)
      -> noise.estimate_noise        local plane residuals: sigma(z) and the sample spacing of this capture
      -> surfaces.segment_surfaces   planes and cylinders with their support (thresholds from the noise);
                                     strips of a thin pipe that the fold test cut apart become its cylinder
      -> support.find_support        the table (or fixture plane) the workpiece stands on
      -> adjacency.adjacent_pairs    surfaces that come near each other (across blurred or unsampled corners)
      -> workpiece.workpiece_labels  with prompts: the prompted surfaces and what touches them in space (not
                                     through the support); seams are only looked for between these
      -> folds.fold_seams            concave folds: plane x plane lines, plane x cylinder rings, clipped to
                                     where both surfaces have support; open roots (V-groove gaps)
      -> gaps.gap_seams              butt gaps: coplanar surfaces whose facing boundaries run parallel
      -> grooves.groove_seams        V-grooves with bevels too thin to segment: the trough between two
                                     plates, each bevel fitted on its cross-section at full resolution
      -> steps.step_seams            laps and steps: an upper plate's edge dropped onto the lower plate
      -> refine.refine_seams         both surfaces refitted on full-resolution points near the seam (planes
                                     out to 100 mm on their faces); open roots: root.open_root; the ends
                                     where both faces' points are, onto a face's straight edge
                                     (seam_ends.supported_ends)
      -> merge.merge_collinear       pieces of one straight seam joined
      -> visibility.clip_to_view     kept where both faces are seen at under 75 degrees (78 for a face that
                                     fits its surface within 1.5 sigma, not across a gap), in runs >= 15 mm
      -> corners.join_corners        two seams meeting at a corner end at their lines' crossing

Lengths in metres, angles in radians inside; the thresholds are multiples of the measured noise and of
the sample spacing, so that one set of constants holds from 0.3 to 0.9 m and from structured light to a
noisy stereo camera.
"""
