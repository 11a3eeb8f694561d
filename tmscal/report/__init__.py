"""Rendering: the text tables of ``tmscal solve``, ``study``, ``compare`` and the adaptive
prediction (:mod:`.text`, :mod:`.compare`), the figures (:mod:`.plots`) and the HTML page of
``tmscal report`` (:mod:`.html`). What is rendered is computed by :mod:`tmscal.solving`."""
