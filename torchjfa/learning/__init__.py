"""torchjfa.learning"""
