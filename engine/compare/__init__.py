"""Two runs compared pixel by pixel (``deepc compare``): ours under other options, or COLMAP's and OpenMVS's maps.

Modules: ``dmap`` (OpenMVS's depth-data files), ``sources`` (opening a run of any of the three systems),
``pixels`` (one view's two depth maps against GT and each other), ``our_fusion`` (a run's maps fused by ours),
``comparison`` (views matched by image name,
the common size, the overall shares and the fused clouds' scores).
"""
