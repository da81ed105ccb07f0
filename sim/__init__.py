"""normbox_lab.sim"""
