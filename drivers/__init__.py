"""normbox_lab.drivers"""
