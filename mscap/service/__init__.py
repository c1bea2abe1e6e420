"""The multi-start service: the MPI farm, starts, selection of k, the HDF5 store."""
