"""Ball model, flight physics (:mod:`.physics`), reference-trajectory fit (:mod:`.fit`) and
baseball pitch metrics (:mod:`.metrics`). Import from the submodules."""
