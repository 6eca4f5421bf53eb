"""Diagnosis: replay and residuals, localisation, the named-physics catalogue's hypotheses
(``sensors``, ``steering``, ``longitudinal`` on the shared ``hypothesis`` interface and
``common`` pieces; the longitudinal inputs a recording holds in ``lon_inputs``, its road grade
in ``lon_grade``, its gears in ``gear_data``, and the hypotheses that depend on them in
``lon_extra``: ``gears``, ``actuator_saturation``, ``unobserved_braking`` from ``braking``),
the sensor pairs compared (``agreement``: ``accelerometer`` against the speed's derivative,
``wheelspeeds`` against the yaw rate), their acceptance (``candidates``) and combination
(``stacking``), an unexplained change (``unexplained``), the overall verdict
(``verdict``), the parameter files written (``params_out``), the orchestration (``diagnose``),
the HTML report with how numbers are shown (``report``, ``display``) and the benchmark
recordings (``testdata``).
May import every other hmpc.models stage; never controller or tools.
"""
