"""The stop on the simulated robot: contact plant and servos, sensors and state estimation,
the online controller and its options (`ControllerOptions`), perturbations, success criteria,
the offline-filter comparison mode and the physics sweep."""
