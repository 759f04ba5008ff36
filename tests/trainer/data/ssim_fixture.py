import numpy as np
from skimage.metrics import structural_similarity
H, W, C = 48, 40, 3
a = np.zeros((H, W, C)); noise = np.zeros((H, W, C))
for c in range(C):
    for y in range(H):
        for x in range(W):
            a[y, x, c] = ((x * 7 + y * 3 + c * 50 + (x * y) % 13) % 256) / 255.0
            n = (x * 1103515245 + y * 12345 + c * 2654435761) % 2**31
            noise[y, x, c] = (n % 201 - 100) / 1000.0
a = a.astype(np.float32).astype(np.float64)
b = np.clip(a + noise, 0, 1).astype(np.float32).astype(np.float64)
d = np.clip(a * 0.5 + 0.25, 0, 1).astype(np.float32).astype(np.float64)
kw = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=2)
print("noisy %.12f" % structural_similarity(a, b, **kw))
print("contrast %.12f" % structural_similarity(a, d, **kw))
print("same %.12f" % structural_similarity(a, a, **kw))
