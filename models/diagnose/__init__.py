"""Diagnosis: replay and residuals, localisation, the named-physics catalogue's hypotheses
(``sensors``, ``steering``, ``longitudinal`` on the shared ``hypothesis`` interface and
``common`` pieces), their acceptance (``candidates``) and combination (``stacking``), an
unexplained change (``unexplained``), the parameter files written (``params_out``), the
orchestration (``diagnose``), the HTML report and the benchmark recordings (``testdata``).
May import every other hmpc.models stage; never controller or tools.
"""
