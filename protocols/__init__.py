"""normbox_lab.protocols"""
