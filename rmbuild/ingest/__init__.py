"""What every input format goes through after its reader: validation, phone PDR where only raw IMU
exists, attachment of readings to pose nodes (:mod:`.core`), warnings about the evidence (:mod:`.checks`),
and the split of a multi-floor input into floors (:mod:`.floors`, :mod:`.barometer`)."""
