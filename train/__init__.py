"""Training (SB3 PPO/SAC) and headless evaluation entry points."""
