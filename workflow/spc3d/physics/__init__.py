"""The SPC photon physics, below every room that reads photons.

spc          1-bit frames (Poisson arrivals, dead time, q, T, dark counts) and flux estimates
flux_scale   the simulated exposure: the flux scale that gives a scene its mean detection rate
montecarlo   Monte-Carlo renewal SPAD simulator (the tests' reference for ``spc``)
sensors      monochrome and colour-filter-array SPAD sensors: masks, mosaics, demosaicing, masked MLE
hot_pixels   hot-pixel detection and maps
record       an SPC folder's ``spc.json`` read back: physics, capture factor S, capture sensor
"""
