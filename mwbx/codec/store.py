"""placeholder"""
class CompressedQposStore:
  pass
