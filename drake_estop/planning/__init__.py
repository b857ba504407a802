"""Pure numeric planning (numpy, no Drake systems): the LIPM (eq. 4-14), the walking
pattern, the stop condition (eq. 17-22, 29), Newton (eq. 21-26, 29-31), the four-phase
stop plan and its per-tick rollout."""
