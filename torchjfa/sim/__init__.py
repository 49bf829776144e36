"""torchjfa.sim"""
