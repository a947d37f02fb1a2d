"""``deepc compare``'s outputs beyond the terminal: the HTML report and the map PNGs (``report``)."""
