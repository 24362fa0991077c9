"""What a run writes and watches: HDF5/XDMF results (:mod:`.output`), checkpoints
(:mod:`.checkpoint`), progress lines and stop requests (:mod:`.monitors`).
"""
