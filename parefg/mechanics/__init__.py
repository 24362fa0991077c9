"""Contact mechanics on Gamma_C: penalty contact with return-mapping friction
(:mod:`.contact`) and the friction laws that decide where friction acts (:mod:`.friction`).
"""
