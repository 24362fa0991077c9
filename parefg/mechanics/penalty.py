"""The penalty factors of the method, registered by kind in :data:`PENALTY_KINDS` (SPEC 4).

Each kind is a ``[penalty] alpha_<kind>`` key (default: ``alpha``) and the field of the
same name of the Scene's penalty section (:class:`~parefg.scene.sections.PenaltySection`).
Not collective.
"""

#: kind -> the constraint its factor enforces
PENALTY_KINDS = {
    "dirichlet": "alpha_D: u = ubar on Gamma_D (the G_D term of A_const)",
    "contact": "alpha_C: the normal pressure alpha_C (u_nu - s)^+ on Gamma_C (ContactLaw)",
    "friction": "alpha_T: the friction spring alpha_T (u_tau - xi) below the bound (ContactLaw)",
}
