#!/usr/bin/env python3
"""A TCP proxy that caps the bytes per second sent from its clients to the upstream server (a
building's Wi-Fi between a robot and central, as a real process for benchmarks).

    python bench/ros_mongo/throttle_proxy.py --port 6001 --upstream 127.0.0.1:5984 --bytes-per-s 2e6

One token bucket (bursts of 0.1 s) for all client connections together; answers from upstream are
not capped. Prints one line when listening; on SIGINT/SIGTERM prints the bytes forwarded.
"""
import argparse
import asyncio
import json
import signal
import sys
import time


class Bucket:
    def __init__(self, rate: float):
        self.rate, self.burst = rate, rate * 0.1
        self.tokens, self.stamp = self.burst, time.monotonic()
        self.lock = asyncio.Lock()
        self.forwarded = 0

    async def take(self, nbytes: int) -> None:
        async with self.lock:  # one sender at a time: the link is shared
            now = time.monotonic()
            self.tokens = min(self.burst, self.tokens + (now - self.stamp) * self.rate)
            self.stamp = now
            self.tokens -= nbytes
            if self.tokens < 0:
                await asyncio.sleep(-self.tokens / self.rate)  # the link's pace
            self.forwarded += nbytes


async def pipe(reader, writer, bucket=None) -> None:
    try:
        while True:
            data = await reader.read(16384)
            if not data:
                break
            if bucket is not None:
                await bucket.take(len(data))
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        writer.close()


async def serve(port: int, upstream: str, rate: float) -> None:
    host, upstream_port = upstream.rsplit(":", 1)
    bucket = Bucket(rate)

    async def handle(client_reader, client_writer):
        try:
            server_reader, server_writer = await asyncio.open_connection(host, int(upstream_port))
        except OSError:
            client_writer.close()
            return
        await asyncio.gather(pipe(client_reader, server_writer, bucket),
                             pipe(server_reader, client_writer))

    server = await asyncio.start_server(handle, "127.0.0.1", port)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    print(f"throttle proxy on 127.0.0.1:{port} -> {upstream} at {rate:.0f} B/s", flush=True)
    async with server:
        await stop.wait()
    print(json.dumps({"forwarded_bytes": bucket.forwarded}), flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--upstream", required=True, help="host:port")
    parser.add_argument("--bytes-per-s", type=float, required=True)
    args = parser.parse_args()
    asyncio.run(serve(args.port, args.upstream, args.bytes_per_s))
    return 0


if __name__ == "__main__":
    sys.exit(main())
