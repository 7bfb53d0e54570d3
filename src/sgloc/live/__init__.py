"""Robots connected live over Zenoh: `sgloc serve` hosts one online session that robots stream
keyframes to and that sends each robot its fleet correction (`server`), a robot-side client
(`client`), sgloc's own compact messages (`messages`), playing a recorded run to a server
(`stream`) and the live view in Foxglove (`view`, its messages in `view_messages`). Needs the
extra `sgloc[live]`; nothing here is imported by `import sgloc`."""
