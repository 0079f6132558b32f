"""``python -m ubf_async.inspector`` — look into a running robot from the command line.

ROS-2-like subcommands, each a separate short-lived zenoh session:

* ``robots`` — every robot alive on the network (a fleet's router): components, tick rates,
  who wins;
* ``components`` — the live components: one name per line, sorted, from the liveliness
  tokens ``ubf/<robot>/alive/*`` (``--long`` adds heartbeat health);
* ``keys`` — the keys that carry samples, with message counts and rates over ``--seconds``;
* ``echo KEY`` — samples on a key (or key expression), decoded and validated like the robot
  does; malformed payloads are printed as errors, never crash the tool;
* ``state`` — the controller's view: tick rate, drive command, every source with its age
  (and whether it is stale), and the last tick's explanation (who voted what, who won);
* ``tree show | set-arbiter | set-child | load`` — the running behaviour tree, and live
  changes to it through the robot's tree service (``ubf/<robot>/tree``, docs/protocol.md,
  "Live tree changes"). Exit status 1 when the robot refuses a change (it then keeps its
  tree as it was), 2 when no robot answers.

It joins the robot as a zenoh **client** of the endpoint it connects to (default
``tcp/127.0.0.1:7447``, where ``python -m ubf_async.launch`` listens), so the robot's peer
answers for every process attached to it. It declares no liveliness token: it never shows up
in ``components``.

The package's modules, by concern:

* :mod:`.program` — ``main``: open a session that reaches the robot, run the verb;
* :mod:`.parser` — the command line: the top-level parser and the connection flags;
* :mod:`.graph` — ``robots``, ``components``, ``keys``, ``info``: what is alive, what it
  publishes;
* :mod:`.samples` — ``echo``, ``hz``, ``bw``: the samples on a key;
* :mod:`.state` — ``state`` and the ``--watch`` refresh;
* :mod:`.tree` — ``tree`` and its verbs;
* :mod:`.pub` — ``pub``;
* :mod:`.common` — what the verbs share: keys resolved, samples decoded, JSON, publishers.

Re-exported here: ``main`` and what tests and other modules use.
"""

from ubf_async.tools.inspector.common import expected_schema, resolve_key
from ubf_async.tools.inspector.parser import PROG, build_parser
from ubf_async.tools.inspector.program import main, run
from ubf_async.tools.inspector.samples import format_sample
from ubf_async.tools.inspector.state import format_clock_domain, format_state
from ubf_async.tools.inspector.tree import tree_request_data

__all__ = ["PROG", "build_parser", "expected_schema", "format_clock_domain", "format_sample",
           "format_state", "main", "resolve_key", "run", "tree_request_data"]
