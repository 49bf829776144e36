"""torchjfa.experiments"""
