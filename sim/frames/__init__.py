"""What a run gives out: probes and fields at a state (probes), the viewer's surface (display)
and the result files (results)."""
