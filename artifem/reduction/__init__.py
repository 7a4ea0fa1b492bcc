"""Reduced-coordinate models (Lloyd et al. 2019, section 2): bases, integration points,
reduced bodies, and the reductor that turns a scene into the same scene with reduced bodies.

    from artifem.reduction import ReducibleScene, Training, Basis, Points, reduce
"""

from artifem import lazy_exports

#: public name -> the module that defines it
_PUBLIC = {
    **dict.fromkeys(
        ["ReducibleScene", "Training", "Basis", "Points", "ReducedModel", "reduce"],
        "artifem.reduction.reductor",
    ),
    **dict.fromkeys(
        [
            "linear_modes",
            "extended_modes",
            "modal_derivative_basis",
            "pod_basis",
            "body_mass",
            "mass_matrix",
        ],
        "artifem.reduction.bases",
    ),
    **dict.fromkeys(["ReducedFemBody", "all_points"], "artifem.reduction.reduced_body"),
    **dict.fromkeys(["each_alone", "random_schedules"], "artifem.reduction.schedules"),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
