"""torchjfa.data"""
