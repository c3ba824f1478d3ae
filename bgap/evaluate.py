from bgap.runner.numerics import command

main = command("bgap.commands.evaluate")
if __name__ == "__main__":
    main()
