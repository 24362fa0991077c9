"""What a run writes and watches: the results writer (:mod:`.output`) with its HDF5
(:mod:`.hdf5`) and XDMF (:mod:`.xdmf`) parts, checkpoints (:mod:`.checkpoint`), progress
lines and stop requests (:mod:`.monitors`).
"""
