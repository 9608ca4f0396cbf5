"""vehicle-detection: find and track vehicles in dashcam video with HOG features and a linear SVM."""

__version__ = "0.1.0"
