"""Mechanics on the discretization: plane-strain elasticity (:mod:`.elasticity`), the
penalty factors (:mod:`.penalty`), and contact on Gamma_C -- the points' normal-tangential
frame (:mod:`.contact_frame`), the contact law (penalty, or Nitsche as a shifted
penalty) with return-mapping friction (:mod:`.contact`), the normal force of a time step
(:mod:`.normal_force`, with its discrete gradient in :mod:`.discrete_gradient`) and the
friction laws that decide where friction acts (:mod:`.friction`).
"""
