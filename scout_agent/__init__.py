"""scout_agent: one legged scout — MuJoCo Aliengo on lunar terrain, proprioceptive estimators, map deltas."""
