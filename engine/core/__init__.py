"""What every stage and run shares: the options framework, the camera convention, errors, observers,
cooperative interruption, depth resampling and handing freed heap memory back (``heap_trim``)."""
