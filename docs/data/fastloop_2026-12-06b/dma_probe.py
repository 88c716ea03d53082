import os, struct, sys, time, signal
fd = os.open("/dev/cpu_dma_latency", os.O_WRONLY)
os.write(fd, struct.pack("i", int(sys.argv[1])))
print("held", sys.argv[1], flush=True)
signal.pause()
