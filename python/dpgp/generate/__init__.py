"""Stage 3, generation: what a fitted model draws new traffic from (:mod:`.distributions`,
:mod:`.motion`), rolling vehicles forward (:mod:`.simulation`), whole scenarios
(:mod:`.scenarios`) and their ASAM OpenSCENARIO export (:mod:`.openscenario`)."""

from . import distributions, motion, openscenario, scenarios, simulation

__all__ = ["distributions", "motion", "openscenario", "scenarios", "simulation"]
