"""Lens-design tools: refocusing (:mod:`.focus`), parameter spaces (:mod:`.space`),
manufacturable sampling (:mod:`.sampling`), the damped-least-squares optimizer
(:mod:`.optimizer`) and its global search (:mod:`.global_search`), tolerancing
(:mod:`.tolerance`) and the lens report (:mod:`.report`)."""
