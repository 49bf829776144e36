"""torchjfa.physical"""
