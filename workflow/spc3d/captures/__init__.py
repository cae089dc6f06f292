"""Real SPAD captures: photon-cube files, capture folders, and their import into the workflow.

photon_cubes  photon-cube files of real SPAD sensors (bit-packed ``.npy``/``.npy.gz``, PNG frames, ``.npz``)
folders       captured SPAD scene folders read back; simulated scenes exported to them
importing     a capture into the workflow: its scene folder (poses given or from COLMAP) and SPC folder
"""
